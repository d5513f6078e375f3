"""Timing: device clocks mapped to host time, and the timing of motion events."""

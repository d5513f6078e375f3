"""Simulated scenarios: whole procedures run on the simulated rig, scored against its truth."""

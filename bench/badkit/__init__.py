"""Helpers of bench/bad_inputs.py: the classes of bad input it sweeps (classes.py)."""

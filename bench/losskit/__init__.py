"""Shared pieces of the frame-loss benchmarks (bench/motion_loss.py, bench/live_blind_time.py, bench/motion_under_loss.py)."""

"""Simulated devices that speak the real protocols, and the scene behind them."""

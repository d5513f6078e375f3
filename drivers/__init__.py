"""Device drivers: one small module per device family."""

"""Vision: marker detection, camera calibration, triangulation, registration, the body finder."""

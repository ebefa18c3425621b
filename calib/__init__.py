"""Camera calibration to the ground plane."""

"""Calibration of rheological parameters (fitting, sensitivity, uncertainty)."""

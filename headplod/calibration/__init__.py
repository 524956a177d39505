"""Stereo calibration of the two cameras from board images (``headplod calibrate``)."""

"""Tests of eit_skin.calibration."""

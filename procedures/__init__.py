"""Procedures: pose sets and planning, the calibration procedure, the live monitor."""

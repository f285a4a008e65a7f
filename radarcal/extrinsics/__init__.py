"""Extrinsic calibration solvers (LiDAR-camera, ...)."""

"""Extrinsic calibration cores: radar <-> LiDAR (corner reflectors), LiDAR <-> LiDAR (registration)."""

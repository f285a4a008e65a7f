"""Moved to :mod:`radarcal.extrinsics.radar.lidar_lidar`; this name re-exports it for existing imports."""

from radarcal.extrinsics.radar.lidar_lidar import *
from radarcal.extrinsics.radar.lidar_lidar import __all__  # noqa: F401

"""Moved to :mod:`radarcal.extrinsics.radar.lidar_lidar`; this name re-exports it for existing imports."""

from radarcal.extrinsics.radar.lidar_lidar import *  # noqa: F403 - the old module name re-exports the package
from radarcal.extrinsics.radar.lidar_lidar import __all__  # noqa: F401

"""Moved to :mod:`radarcal.extrinsics.radar` (split along its jobs); this name re-exports it for existing imports."""

from radarcal.extrinsics.radar import *
from radarcal.extrinsics.radar import __all__  # noqa: F401

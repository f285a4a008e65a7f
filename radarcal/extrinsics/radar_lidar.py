"""Moved to :mod:`radarcal.extrinsics.radar` (split along its jobs); this name re-exports it for existing imports."""

from radarcal.extrinsics.radar import *  # noqa: F403 - the old module name re-exports the package
from radarcal.extrinsics.radar import __all__  # noqa: F401

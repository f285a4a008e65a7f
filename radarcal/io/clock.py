"""The host clock every live input stamps its data with (camera frames, LiDAR packets, serial bytes): seconds on
``time.monotonic()`` since this process started using it. Recordings store these times; a replay reproduces them."""

from __future__ import annotations

import time

__all__ = ["EPOCH", "now"]

EPOCH = time.monotonic()


def now() -> float:
    return time.monotonic() - EPOCH

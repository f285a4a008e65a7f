"""Convert numpy-laden results to plain Python for YAML/JSON (the one place that does it)."""

from __future__ import annotations

import math
from pathlib import PurePath
from typing import Any

import numpy as np

__all__ = ["to_plain"]


def to_plain(obj: Any, json_safe: bool = False) -> Any:
    """numpy arrays/scalars -> lists/Python scalars, dict keys -> str, paths -> str, recursively.

    ``json_safe=True`` also turns non-finite floats into ``None`` (strict JSON has no NaN/Infinity)."""
    if isinstance(obj, dict):
        return {str(k): to_plain(v, json_safe) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v, json_safe) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_plain(obj.tolist(), json_safe) if json_safe else obj.tolist()
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, PurePath):
        return str(obj)
    if json_safe and isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj

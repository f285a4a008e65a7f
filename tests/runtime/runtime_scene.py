"""Scene helpers for the runtime tests (imported by the test modules; fixtures live in conftest.py)."""

from __future__ import annotations

import numpy as np


def robot_cloud(center_xy, radius=0.25, height=0.45, n=400, rng=None, viewer_xy=(-1.0, 7.5)):
    """Points a LiDAR at ``viewer_xy`` sees on a vertical cylinder standing on z = 0 (a robot): only the visible
    half, sampled uniformly across its apparent width (as a scanner does)."""
    rng = rng or np.random.default_rng(0)
    c = np.asarray(center_xy, float)
    to_viewer = np.asarray(viewer_xy, float) - c
    base = np.arctan2(to_viewer[1], to_viewer[0])
    ang = base + np.arcsin(rng.uniform(-1, 1, n))
    z = rng.uniform(0.05, height, n)
    return np.column_stack([c[0] + radius * np.cos(ang), c[1] + radius * np.sin(ang), z])

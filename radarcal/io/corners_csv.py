"""Manual LiDAR-camera correspondences: CSV rows ``x,y,z,u,v`` (LiDAR metres, image pixels), optional header,
``#`` comments, optional 6th column ``view`` (index of the --image/--cloud pair, default 0)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from radarcal.errors import InputError, read_text

__all__ = ["read_corners_csv", "read_uv_csv"]


def _rows(path: Path, min_cols: int) -> list[list[float]]:
    text = read_text(path)
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        toks = [t for t in line.replace(";", ",").replace("\t", ",").replace(" ", ",").split(",") if t]
        try:
            vals = [float(t) for t in toks]
        except ValueError:
            if not rows and lineno <= 2:
                continue  # header
            raise InputError(path, f"line {lineno}: not numbers: {line[:60]!r}") from None
        if len(vals) < min_cols:
            raise InputError(path, f"line {lineno}: expected at least {min_cols} values, got {len(vals)}")
        if not np.all(np.isfinite(vals)):
            raise InputError(path, f"line {lineno}: non-finite value")
        rows.append(vals)
    return rows


def read_corners_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p_lidar (N,3), uv (N,2), view (N,) int) from a correspondence CSV; at least 4 rows."""
    path = Path(path)
    rows = _rows(path, 5)
    if len(rows) < 4:
        raise InputError(path, f"need at least 4 correspondences (x,y,z,u,v), got {len(rows)}")
    a = np.array([r[:6] + [0.0] * (6 - len(r[:6])) for r in rows])
    return a[:, :3], a[:, 3:5], a[:, 5].astype(int)


def read_uv_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Clicked image corners of boards: rows ``u,v[,view]``, 4 consecutive rows per board (any corner order).
    Returns (uv (4B,2), view (4B,))."""
    path = Path(path)
    rows = _rows(path, 2)
    if len(rows) == 0 or len(rows) % 4:
        raise InputError(path, f"expected 4 rows (u,v) per board, got {len(rows)} rows")
    a = np.array([r[:3] + [0.0] * (3 - len(r[:3])) for r in rows])
    return a[:, :2], a[:, 2].astype(int)

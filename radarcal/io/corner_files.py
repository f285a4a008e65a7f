"""Chessboard corners detected by another tool, for ``radarcal intrinsics --corners FILE`` (no images needed).

- **mrcal corners cache** (``.vnl``, as written by ``mrgingham`` / read by ``mrcal-calibrate-cameras --corners-cache``):
  a ``# filename x y [weight]`` legend, then one row per corner, ``cols x rows`` rows per image in row-major order;
  ``-`` marks a corner that was not found; a weight <= 0 marks a corner mrcal flagged as an outlier (dropped here,
  as mrcal does), other weights (decimation level) are ignored.
- **CSV**: rows ``image,id,u,v`` (corner id = row-major index into the board's inner corners) or ``image,u,v`` (all
  corners of each image, row-major); an optional header row, ``#`` comments.

Pixel coordinates as the file gives them (both tools use pixel centres at integer coordinates, as OpenCV).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal.errors import InputError, read_text

__all__ = ["CornerView", "read_corner_file"]


@dataclass
class CornerView:
    name: str  # image name as the file gives it
    uv: np.ndarray  # (N,2) pixels
    ids: np.ndarray  # (N,) row-major inner-corner index


def _split(line: str) -> list[str]:
    return [t for t in line.replace(",", " ").replace(";", " ").replace("\t", " ").split() if t]


def _float(tok: str) -> float:
    return np.nan if tok == "-" else float(tok)


def _read_vnl(path: Path, lines: list[tuple[int, str]], n_corners: int, legend: list[str]) -> list[CornerView]:
    has_weight = "weight" in legend
    names: list[str] = []
    values: list[tuple[float, float, float]] = []
    for lineno, line in lines:
        t = _split(line)
        if len(t) < 3 + has_weight:
            raise InputError(path, f"line {lineno}: expected '{' '.join(legend)}', got {line.strip()[:60]!r}")
        try:
            values.append((_float(t[1]), _float(t[2]), _float(t[3]) if has_weight else 1.0))
        except ValueError:
            raise InputError(path, f"line {lineno}: not numbers: {line.strip()[:60]!r}") from None
        names.append(t[0])
    a = np.array(values).reshape(-1, 3)
    views = []
    order = list(dict.fromkeys(names))
    names_a = np.array(names)
    for name in order:
        rows = np.flatnonzero(names_a == name)
        if len(rows) != n_corners:
            raise InputError(path, f"image {name}: {len(rows)} corner rows, but the board has {n_corners} inner corners (check --cols/--rows)")
        v = a[rows]
        keep = np.isfinite(v[:, 0]) & np.isfinite(v[:, 1]) & (v[:, 2] > 0)
        views.append(CornerView(name, v[keep, :2], np.flatnonzero(keep)))
    return views


def _read_csv(path: Path, lines: list[tuple[int, str]], n_corners: int) -> list[CornerView]:
    per: dict[str, list[tuple[int | None, float, float]]] = {}
    for k, (lineno, line) in enumerate(lines):
        t = _split(line)
        try:
            nums = [float(x) for x in t[1:]]
        except ValueError:
            if k == 0:
                continue  # header
            raise InputError(path, f"line {lineno}: expected image,id,u,v or image,u,v") from None
        if len(nums) not in (2, 3) or not np.all(np.isfinite(nums)):
            raise InputError(path, f"line {lineno}: expected image,id,u,v or image,u,v with finite numbers")
        cid = int(nums[0]) if len(nums) == 3 else None
        if cid is not None and not (0 <= cid < n_corners and nums[0] == cid):
            raise InputError(path, f"line {lineno}: corner id {nums[0]:g} outside 0..{n_corners - 1}")
        per.setdefault(t[0], []).append((cid, nums[-2], nums[-1]))
    views = []
    for name, rows in per.items():
        if rows[0][0] is None:
            if len(rows) != n_corners:
                raise InputError(path, f"image {name}: {len(rows)} rows without ids, but the board has {n_corners} inner corners")
            ids = np.arange(n_corners)
        else:
            ids = np.array([r[0] for r in rows])
            if len(np.unique(ids)) != len(ids):
                raise InputError(path, f"image {name}: a corner id appears twice")
        views.append(CornerView(name, np.array([r[1:] for r in rows], float), ids))
    return views


def read_corner_file(path: str | os.PathLike, n_corners: int) -> list[CornerView]:
    """Views of a corner file (mrcal ``.vnl`` or CSV, detected from the content) for a board of ``n_corners`` inner
    corners; every view keeps its found corners with their row-major ids."""
    path = Path(path)
    text = read_text(path, "corner file")
    lines = [(i, ln) for i, ln in enumerate(text.splitlines(), 1) if ln.strip()]
    legend: list[str] = []
    body = []
    for i, ln in lines:
        if ln.lstrip().startswith("#"):
            toks = _split(ln.lstrip()[1:])
            if toks[:3] == ["filename", "x", "y"]:
                legend = toks
            continue
        body.append((i, ln))
    if not body:
        raise InputError(path, "no corner rows")
    views = _read_vnl(path, body, n_corners, legend) if legend else _read_csv(path, body, n_corners)
    if not views:
        raise InputError(path, "no views")
    return views

"""View selection and coverage, after ROS camera_calibration.

Each view gets the descriptor (X, Y, Size, Skew) in [0, 1]: board centre position (shrunk by half the board size so
large boards are not penalised), sqrt(board area / image area), and 2·|90° − corner angle|. A view is *novel* when
its L1 distance to every kept view exceeds 0.2 (ROS's gate). Coverage per descriptor = observed range / ROS's
target range (0.7, 0.7, 0.4, 0.5), capped at 1; plus the fraction of an 8x6 image grid that holds corners.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Coverage", "view_descriptor", "novel_mask", "coverage", "DESCRIPTOR_NAMES", "TARGET_RANGES"]

DESCRIPTOR_NAMES = ("X", "Y", "Size", "Skew")
TARGET_RANGES = np.array([0.7, 0.7, 0.4, 0.5])


@dataclass
class Coverage:
    progress: dict[str, float]  # per descriptor, 0..1
    lo: dict[str, float]
    hi: dict[str, float]
    grid_fraction: float  # share of 8x6 image cells with at least one corner
    grid: np.ndarray  # (6,8) corner counts
    warnings: list[str]


def _outside(uv: np.ndarray, ids: np.ndarray, grid_shape: tuple[int, int]) -> np.ndarray:
    """Four outer corners (up_left, up_right, down_right, down_left) of a (possibly partial) detection."""
    nc = grid_shape[1]
    r, c = np.divmod(np.asarray(ids, int), nc)
    return np.stack([uv[np.argmin(r + c)], uv[np.argmax(c - r)], uv[np.argmax(r + c)], uv[np.argmax(r - c)]])


def view_descriptor(uv: np.ndarray, ids: np.ndarray, grid_shape: tuple[int, int], image_size: tuple[int, int]) -> np.ndarray:
    """ROS (X, Y, Size, Skew) of one view."""
    w, h = image_size
    uv = np.asarray(uv, float)
    ul, ur, dr, dl = _outside(uv, ids, grid_shape)
    a, b, c = ur - ul, dr - ur, dl - dr
    p, q = b + c, a + b
    area = abs(p[0] * q[1] - p[1] * q[0]) / 2.0
    ab, cb = ul - ur, dr - ur
    denom = np.linalg.norm(ab) * np.linalg.norm(cb)
    ang = np.arccos(np.clip(np.dot(ab, cb) / denom, -1, 1)) if denom > 0 else np.pi / 2
    skew = min(1.0, 2.0 * abs(np.pi / 2 - ang))
    border = np.sqrt(area)
    px = min(1.0, max(0.0, (uv[:, 0].mean() - border / 2) / max(w - border, 1e-9)))
    py = min(1.0, max(0.0, (uv[:, 1].mean() - border / 2) / max(h - border, 1e-9)))
    return np.array([px, py, np.sqrt(area / (w * h)), skew])


def novel_mask(descriptors: np.ndarray, threshold: float = 0.2, kept: np.ndarray | None = None) -> np.ndarray:
    """Greedy novelty gate in input order: a view is kept when its L1 distance to all kept ones exceeds
    ``threshold``. ``kept`` (K,4) are descriptors already accepted before these."""
    d = np.asarray(descriptors, float).reshape(-1, 4)
    store = [] if kept is None else [np.asarray(k, float) for k in np.asarray(kept).reshape(-1, 4)]
    out = np.zeros(len(d), bool)
    for i, x in enumerate(d):  # loop over views (tens to hundreds), not points
        if not store or np.min(np.abs(np.asarray(store) - x).sum(axis=1)) > threshold:
            out[i] = True
            store.append(x)
    return out


def coverage(descriptors: np.ndarray, uv_all: np.ndarray, image_size: tuple[int, int], warn_below: float = 0.5) -> Coverage:
    """Coverage of the used views: descriptor ranges and image-grid occupancy (``uv_all`` (N,2) all corners)."""
    d = np.asarray(descriptors, float).reshape(-1, 4)
    w, h = image_size
    if len(d):
        lo, hi = d.min(axis=0), d.max(axis=0)
    else:
        lo = hi = np.zeros(4)
    prog = np.minimum((hi - lo) / TARGET_RANGES, 1.0)
    uv = np.asarray(uv_all, float).reshape(-1, 2)
    gx = np.clip((uv[:, 0] / w * 8).astype(int), 0, 7)
    gy = np.clip((uv[:, 1] / h * 6).astype(int), 0, 5)
    grid = np.zeros((6, 8), int)
    np.add.at(grid, (gy, gx), 1)
    frac = float(np.mean(grid > 0))
    warnings = [f"coverage {n} = {np.floor(p * 100) / 100:.2f} < {warn_below}: move the board more along {n}" for n, p in zip(DESCRIPTOR_NAMES, prog) if p < warn_below]
    if frac < 0.6:
        warnings.append(f"corners reach only {frac:.0%} of the image (8x6 grid): cover the corners and edges")
    names = DESCRIPTOR_NAMES
    return Coverage(dict(zip(names, prog.tolist())), dict(zip(names, lo.tolist())), dict(zip(names, hi.tolist())), frac, grid, warnings)

"""Correspondences between 2D point sets related by an unknown rigid transform: mutual nearest neighbours and an
exhaustive RANSAC over point pairs shared by several placements."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from radarcal.extrinsics.radar.geometry2d import Pose2, procrustes_2d
from radarcal.extrinsics.radar.geometry2d import wrap_angle as _wrap

__all__ = ["mutual_nn", "robust_match_2d", "robust_match_sets"]


def mutual_nn(a: np.ndarray, b: np.ndarray, gate: float) -> np.ndarray:
    """(K,2) index pairs (i in a, j in b) that are each other's nearest neighbour and closer than ``gate``; points
    (N,D) of any dimension (a flat array is read as 2D points)."""
    a = np.asarray(a, float)
    a = a.reshape(-1, a.shape[-1] if a.ndim > 1 else 2)
    b = np.asarray(b, float).reshape(-1, a.shape[1])
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), int)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    ja = np.argmin(d, axis=1)
    ib = np.argmin(d, axis=0)
    i = np.arange(len(a))
    ok = (ib[ja] == i) & (d[i, ja] < gate)
    return np.stack([i[ok], ja[ok]], axis=1)


def robust_match_2d(
    src: np.ndarray,
    dst: np.ndarray,
    init: Pose2 | None = None,
    gate: float = 0.3,
    max_rotation_from_init: float = np.radians(45.0),
    min_pair_distance: float = 0.3,
) -> tuple[np.ndarray, Pose2 | None]:
    """Correspondences between two 2D point sets related by an unknown rigid transform ``dst ~ R src + t``
    (see :func:`robust_match_sets`). Returns (pairs (K,2), pose) or (empty, None) when fewer than 2 matches exist."""
    pairs, pose = robust_match_sets([src], [dst], init, gate, max_rotation_from_init, min_pair_distance)
    return pairs[0], pose


def robust_match_sets(
    srcs: Sequence[np.ndarray],
    dsts: Sequence[np.ndarray],
    init: Pose2 | None = None,
    gate: float = 0.3,
    max_rotation_from_init: float = np.radians(45.0),
    min_pair_distance: float = 0.3,
    max_hypotheses: int = 400,
) -> tuple[list, Pose2 | None]:
    """One rigid transform ``dst ~ R src + t`` shared by several placements (lists of point sets, one pair per scene).

    Hypotheses: ``init`` itself (when given) and, in every scene, every pair of src points against every ordered pair
    of dst points whose separations agree within ``gate`` (RANSAC over pairs, exhaustive: the sets are small). A
    hypothesis is scored by its mutual-nearest-neighbour inliers within ``gate`` summed over all scenes (ties: the
    smaller mean squared residual), refined in closed form on them and re-matched. With ``init``, hypotheses are limited
    to rotations within ``max_rotation_from_init`` of it. More than ``max_hypotheses`` pair hypotheses are subsampled
    (seeded, so the result is deterministic). Returns (pairs per scene, pose) or (empties, None).
    """
    S = [np.asarray(x, float).reshape(-1, 2) for x in srcs]
    D = [np.asarray(x, float).reshape(-1, 2) for x in dsts]
    hyps: list[Pose2] = [init] if init is not None else []
    for src, dst in zip(S, D):
        hyps += _pair_hypotheses(src, dst, init, gate, max_rotation_from_init, min_pair_distance, max_hypotheses)
    if len(hyps) > max_hypotheses:
        first = hyps[:1] if init is not None else []
        pick = np.random.default_rng(0).choice(len(hyps) - len(first), max_hypotheses, replace=False) + len(first)
        hyps = first + [hyps[k] for k in np.sort(pick)]
    empty = [np.zeros((0, 2), int) for _ in S]
    best = (empty, None, 0, np.inf)
    seen = set()
    for h in hyps:  # loop over hypotheses (a few hundred at most), each vectorised
        key = (round(h.theta, 3), round(float(h.t[0]), 2), round(float(h.t[1]), 2))
        if key in seen:
            continue
        seen.add(key)
        pose, pairs = _refine_hypothesis(h, S, D, init, gate, max_rotation_from_init, empty)
        a, b = _stack_pairs(S, D, pairs)
        if len(a) < 2:
            continue
        cost = float(np.mean(np.sum((pose.apply(a) - b) ** 2, axis=1)))
        if len(a) > best[2] or (len(a) == best[2] and cost < best[3]):
            best = (pairs, pose, len(a), cost)
    return best[0], best[1]


def _pair_hypotheses(src, dst, init, gate, max_rotation_from_init, min_pair_distance, max_hypotheses) -> list[Pose2]:
    """One scene's hypotheses: every src point pair against every ordered dst pair of the same separation (within
    ``gate``; src pairs closer than ``min_pair_distance`` skipped), whole src pairs subsampled (seeded) beyond
    ``max_hypotheses``, rotations limited around ``init``."""
    ns, nd = len(src), len(dst)
    if ns < 2 or nd < 2:
        return []
    i1, i2 = np.triu_indices(ns, 1)
    j1, j2 = np.nonzero(~np.eye(nd, dtype=bool))  # ordered dst pairs
    ds = np.linalg.norm(src[i1] - src[i2], axis=1)
    dd = np.linalg.norm(dst[j1] - dst[j2], axis=1)
    ok = (np.abs(ds[:, None] - dd[None, :]) < gate) & (ds[:, None] > min_pair_distance)
    if ok.sum() > max_hypotheses:  # many points: whole src pairs (seeded random order) until the budget is used,
        rows = np.random.default_rng(1).permutation(len(ok))  # so each chosen pair keeps all its dst partners
        take = np.cumsum(ok[rows].sum(axis=1)) <= max_hypotheses
        take[:4] = True
        keep_rows = np.zeros(len(ok), bool)
        keep_rows[rows[take]] = True
        ok &= keep_rows[:, None]
    pi, pj = np.nonzero(ok)
    va = src[i2[pi]] - src[i1[pi]]
    vb = dst[j2[pj]] - dst[j1[pj]]
    th = np.arctan2(vb[:, 1], vb[:, 0]) - np.arctan2(va[:, 1], va[:, 0])
    if init is not None:
        keep = np.abs(_wrap(th - init.theta)) < max_rotation_from_init
        pi, pj, th = pi[keep], pj[keep], th[keep]
    cs = 0.5 * (src[i1[pi]] + src[i2[pi]])
    cd = 0.5 * (dst[j1[pj]] + dst[j2[pj]])
    c, s_ = np.cos(th), np.sin(th)
    t = cd - np.stack([c * cs[:, 0] - s_ * cs[:, 1], s_ * cs[:, 0] + c * cs[:, 1]], axis=1)
    return [Pose2(float(th[k]), t[k]) for k in range(len(th))]


def _match_all(pose: Pose2, S, D, gate) -> list:
    return [mutual_nn(pose.apply(a), b, gate) for a, b in zip(S, D)]


def _stack_pairs(S, D, pairs) -> tuple[np.ndarray, np.ndarray]:
    """Matched points of all scenes stacked: (src (n,2), dst (n,2))."""
    a = np.concatenate([S[k][p[:, 0]] for k, p in enumerate(pairs)]) if pairs else np.zeros((0, 2))
    b = np.concatenate([D[k][p[:, 1]] for k, p in enumerate(pairs)]) if pairs else np.zeros((0, 2))
    return a, b


def _refine_hypothesis(h: Pose2, S, D, init, gate, max_rotation_from_init, empty) -> tuple[Pose2, list]:
    """Mutual-NN match under ``h``, closed-form refit on the matches, re-match; up to three rounds or until the
    matches stop changing (``empty`` matches when the refit leaves the rotation limit around ``init``)."""
    pose, pairs = h, _match_all(h, S, D, gate)
    for _ in range(3):
        a, b = _stack_pairs(S, D, pairs)
        if len(a) < 2:
            break
        pose = procrustes_2d(a, b)
        if init is not None and abs(_wrap(pose.theta - init.theta)) > max_rotation_from_init:
            pairs = empty
            break
        new = _match_all(pose, S, D, gate)
        if all(np.array_equal(x, y) for x, y in zip(new, pairs)):
            break
        pairs = new
    return pose, pairs


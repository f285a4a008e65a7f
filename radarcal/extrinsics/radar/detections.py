"""Radar side: averaging repeated frames, the patent's A/B/C sets, the quantisation report."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["FRAME_GATE", "FilterResult", "aggregate_frames", "filter_detections", "frames_per_source", "quantisation_report"]

FRAME_GATE = 0.3  # m: one source's detections over a placement's frames lie within this of each other (single linkage)


def aggregate_frames(xy: np.ndarray, gate: float = FRAME_GATE, min_fraction: float = 0.3, rcs: np.ndarray | None = None,
                     rcs_split_db: float = 4.0, frames: int | None = None) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Average repeated detections of one radar over many frames: single-linkage clusters within ``gate``, cluster
    means; clusters seen in fewer than ``min_fraction`` of the frames a source seen in every frame appears in (the
    most-seen cluster's count, at most the median count of those seen more than once: :func:`_frames_seen`) are
    dropped (ghosts).

    With ``rcs`` (dBsm per detection) a cluster of three or more whose RCS values form two classes (one may be a
    single frame) more than ``rcs_split_db`` (and 3 within-class sigma) apart is split in two (a ground-bounce multipath ghost sits a few decimetres behind its reflector, ~8 dB weaker, and would
    otherwise be averaged into it); the means are then inverse-variance means (weights ``10^(RCS/10)``) and each
    cluster's RCS is the power mean (``n`` frames at it carry the cluster's total weight). A cluster of more
    detections than ``frames`` (how many a source seen in every frame leaves in one placement: this radar's
    :func:`frames_per_source` over the session; this call's own estimate when None) holds several sources and is cut
    (:func:`_split_crowded`) after the RCS split; the ghost rule then counts on the cut clusters (:func:`_frames_seen`
    of this call). Returns (means (K,2), counts (K,)) or, with ``rcs``, (means, counts, RCS (K,))."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) == 0:
        return (xy, np.zeros(0, int)) if rcs is None else (xy, np.zeros(0, int), np.zeros(0))
    ncomp, lab = _linkage_clusters(xy, gate)
    if rcs is not None:
        rc = np.asarray(rcs, float).reshape(-1)
        rc = np.where(np.isfinite(rc), rc, 0.0)
        lab = lab.copy()
        queue = list(range(ncomp))
        while queue:  # clusters (few): two RCS classes (least within-class variance) when clearly apart, recursively
            c = queue.pop()
            idx = np.nonzero(lab == c)[0]
            if len(idx) < 3:
                continue
            v = np.sort(rc[idx])
            k = np.arange(1, len(v))  # split after the k lowest (a class may be one frame: a reflector's frame among clutter)
            if len(k) == 0:
                continue
            cs, cs2 = np.cumsum(v), np.cumsum(v**2)
            lo_m, hi_m = cs[k - 1] / k, (cs[-1] - cs[k - 1]) / (len(v) - k)
            within = (cs2[-1] - k * lo_m**2 - (len(v) - k) * hi_m**2) / len(v)
            b = int(np.argmin(within))
            diff = hi_m[b] - lo_m[b]
            if diff > rcs_split_db and diff > 3 * np.sqrt(max(within[b], 0.0)):
                lab[idx[rc[idx] < v[k[b]]]] = ncomp
                queue += [c, ncomp]
                ncomp += 1
    lab, ncomp = _split_crowded(xy, lab, ncomp, frames)
    counts = np.bincount(lab, minlength=ncomp)
    # with RCS: inverse-variance means (a radar's position variance ~ 1 / SNR ~ 10^(-RCS/10)), so a weak echo merged
    # into a reflector's cluster (a ghost, clutter, a frame of a turned reflector) counts as little as its noise says
    w = np.ones(len(xy)) if rcs is None else 10 ** ((rc - rc.max()) / 10)
    wsum = np.bincount(lab, weights=w, minlength=ncomp)
    sums = np.zeros((ncomp, 2))
    np.add.at(sums, lab, xy * w[:, None])
    means = sums / wsum[:, None]
    keep = counts >= max(1, min_fraction * _frames_seen(counts))
    if rcs is None:
        return means[keep], counts[keep]
    rmean = rc.max() + 10 * np.log10(wsum / counts)  # power mean: n frames at this RCS carry the cluster's total weight
    return means[keep], counts[keep], rmean[keep]


def _linkage_clusters(xy: np.ndarray, gate: float) -> tuple[int, np.ndarray]:
    """Single-linkage clusters of (N,2) points within ``gate`` (m): (number, label per point)."""
    from scipy.sparse import coo_matrix

    pairs = cKDTree(xy).query_pairs(gate, output_type="ndarray")
    return connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xy), len(xy))), directed=False)


def frames_per_source(xy_sets: Sequence[np.ndarray], gate: float = FRAME_GATE) -> int | None:
    """How many detections a source seen in every frame leaves in one placement, pooled over one radar's detection
    sets of a session's placements (radars may record different numbers of frames): the median count of the
    single-linkage clusters within ``gate`` (m) seen more than once, rounded up (one placement alone has too few
    clusters to tell). None when no cluster repeats (single frames)."""
    counts = [np.bincount(_linkage_clusters(xy, gate)[1]) for xy in (np.asarray(v, float).reshape(-1, 2) for v in xy_sets) if len(xy)]
    many = np.concatenate(counts) if counts else np.zeros(0, int)
    many = many[many > 1]
    return int(np.ceil(np.median(many))) if len(many) else None


def _split_crowded(xy: np.ndarray, lab: np.ndarray, ncomp: int, frames: int | None = None) -> tuple[np.ndarray, int]:
    """A source is seen at most once per frame: a cluster holding more detections than ``frames`` (default: this
    set's :func:`_frames_seen`, rounded up) merges several (a weak echo chained to the clutter at its tripod's feet)
    and is cut once into ``ceil(n / frames)`` compact parts (average linkage; the parts need not be equal, and
    identical points -- a gridded object list -- stay together). Returns the new labels and their number."""
    from scipy.cluster.hierarchy import fcluster, linkage

    counts = np.bincount(lab, minlength=ncomp)
    frames = int(np.ceil(_frames_seen(counts))) if frames is None else int(frames)
    if frames < 2:
        return lab, ncomp
    lab = lab.copy()
    for c in np.nonzero(counts > frames)[0]:  # crowded clusters (few)
        idx = np.nonzero(lab == c)[0]
        k = int(np.ceil(len(idx) / frames))
        part = fcluster(linkage(xy[idx], method="average"), k, criterion="maxclust")
        for j in range(2, part.max() + 1):
            lab[idx[part == j]] = ncomp
            ncomp += 1
    return lab, ncomp


def _frames_seen(counts: np.ndarray) -> float:
    """How many frames a source seen in every frame appears in: the most-seen cluster's count, but at most the median
    count of the clusters seen more than once -- a cluster holding more detections than there are frames merges
    several sources (clutter beside a tripod foot and its neighbour, a multipath ghost) and would make a turned
    reflector's one or two frames look like a ghost's."""
    many = counts[counts > 1]
    return float(min(counts.max(), np.median(many))) if len(many) else float(counts.max())


@dataclass
class FilterResult:
    """Detections of all radars in the reference radar frame, split as in the patent.

    ``A``: indices of detections inside the region; ``B``: those seen by two or three radars (a detection of another
    radar within ``gate``); ``C``: seen by one radar only. ``groups`` (per B detection) lists the merged cluster id.
    """

    points: np.ndarray  # (M,2) all detections in the reference frame
    radar: np.ndarray  # (M,) radar index
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    cluster: np.ndarray  # (M,) cluster id (-1 outside the region)
    cluster_means: np.ndarray  # (K,2)
    cluster_radars: np.ndarray  # (K,) number of distinct radars in the cluster

    def counts(self) -> dict:
        return {"A": len(self.A), "B": len(self.B), "C": len(self.C)}


def filter_detections(points_ref: Sequence[np.ndarray], forward: tuple[float, float] = (0.0, 5.0), lateral: tuple[float, float] = (-5.0, 5.0),
                      gate: float = 0.3) -> FilterResult:
    """Sets A/B/C of the patent from every radar's detections already mapped into the reference radar frame.

    The patent's region is x in (-5, 5), y in (0, 5) with y forward; here ``forward`` bounds x and ``lateral`` bounds
    y of the reference radar frame (x forward, y left)."""
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 2) for p in points_ref]) if len(points_ref) else np.zeros((0, 2))
    rid = np.concatenate([np.full(len(np.asarray(p).reshape(-1, 2)), i) for i, p in enumerate(points_ref)]) if len(points_ref) else np.zeros(0, int)
    inside = (pts[:, 0] > forward[0]) & (pts[:, 0] < forward[1]) & (pts[:, 1] > lateral[0]) & (pts[:, 1] < lateral[1])
    A = np.nonzero(inside)[0]
    cluster = np.full(len(pts), -1)
    means = np.zeros((0, 2))
    nrad = np.zeros(0, int)
    B = C = np.zeros(0, int)
    if len(A):
        pa = pts[A]
        pairs = cKDTree(pa).query_pairs(gate, output_type="ndarray")
        pairs = pairs[rid[A][pairs[:, 0]] != rid[A][pairs[:, 1]]]  # only links between different radars
        from scipy.sparse import coo_matrix

        ncomp, lab = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(A), len(A))), directed=False)
        cluster[A] = lab
        means = np.zeros((ncomp, 2))
        np.add.at(means, lab, pa)
        means /= np.bincount(lab, minlength=ncomp)[:, None]
        nrad = np.array([len(np.unique(rid[A][lab == k])) for k in range(ncomp)])  # loop over clusters
        multi = nrad[lab] >= 2
        B, C = A[multi], A[~multi]
    return FilterResult(pts, rid, A, B, C, cluster, means, nrad)


def quantisation_report(xy: np.ndarray, candidates: Sequence[float] = (0.2, 0.1, 0.25, 0.5, 0.05)) -> dict:
    """Detect a coordinate grid (ARS408 object lists: 0.2 m) and what it costs: the per-axis error of a quantised
    value is uniform with sigma ``q / sqrt(12)``; it is a deterministic function of the true position, so averaging
    frames does not remove it (only noise larger than ``q`` would dither it away)."""
    xy = np.asarray(xy, float).ravel()
    xy = xy[np.isfinite(xy)]
    for q in candidates:
        if len(xy) >= 4 and np.all(np.abs(xy / q - np.round(xy / q)) < 1e-3):
            return {"quantised": True, "step_m": q, "sigma_per_axis_m": q / np.sqrt(12.0), "averaging_removes_it": False,
                    "note": f"coordinates lie on a {q:g} m grid: a {q / np.sqrt(12):.3f} m per-axis error that averaging frames cannot remove"}
    return {"quantised": False, "step_m": None, "sigma_per_axis_m": 0.0, "averaging_removes_it": True, "note": "no coordinate grid detected"}


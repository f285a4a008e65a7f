"""The intrinsics and stereo sections of the report, from :class:`radarcal.intrinsics.session.IntrinsicsSession` /
``StereoSession`` files (exactly the names ``radarcal intrinsics`` writes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radarcal.camera import Camera
from radarcal.intrinsics.session import IntrinsicsSession, StereoSession
from radarcal.report import intrinsics as ri
from radarcal.report.html import Section, Table
from radarcal.report.sections_common import FigureAdder, camera_param_table, read_image_file, str_list

__all__ = ["IntrinsicsData", "intrinsics_data", "intrinsics_section", "stereo_section"]


@dataclass
class IntrinsicsData:
    """An intrinsics session arranged for the figures (any field may be None when the session lacks it)."""

    camera: Camera
    uv: np.ndarray | None = None  # (N,2) observed corners
    residual: np.ndarray | None = None  # (N,2) observed − projected, px
    corner_view: np.ndarray | None = None  # (N,) index into view_names
    corner_outlier: np.ndarray | None = None  # (N,) bool
    view_names: list[str] = field(default_factory=list)
    view_files: list[str] = field(default_factory=list)  # image file of each view, when the session names them
    view_error: np.ndarray | None = None  # (V,) px
    view_error_label: str = "mean |residual| (px)"
    view_outlier: np.ndarray | None = None  # (V,) bool
    rejected: list[list[str]] = field(default_factory=list)  # [input, reason] of inputs never solved
    noise_px: float | None = None
    rms_px: float | None = None
    sigma_u: np.ndarray | None = None
    sigma_v: np.ndarray | None = None
    sigma_px: np.ndarray | None = None
    valid_threshold_px: float = 1.0
    cv_u: np.ndarray | None = None
    cv_v: np.ndarray | None = None
    cv_diff_px: np.ndarray | None = None
    cv_sigma_px: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)

    def worst_view(self) -> int | None:
        """Index of the solved view with the largest error among those the solver kept (None if unknown)."""
        if self.view_error is None or np.size(self.view_error) == 0:
            return None
        e = np.asarray(self.view_error, float).copy()
        if self.view_outlier is not None and not np.all(self.view_outlier):
            e[np.asarray(self.view_outlier, bool)] = -np.inf
        return int(np.nanargmax(np.where(np.isfinite(e), e, -np.inf)))

    def view_mask(self, k: int) -> np.ndarray:
        """Mask of the corners of solved view ``k``."""
        return np.asarray(self.corner_view, int).ravel() == k

    def inlier_residuals(self) -> np.ndarray | None:
        """Residuals of corners that are neither outliers nor in an outlier view."""
        if self.residual is None:
            return None
        r = np.asarray(self.residual, float).reshape(-1, 2)
        bad = np.zeros(len(r), bool) if self.corner_outlier is None else np.asarray(self.corner_outlier, bool).ravel()
        if self.view_outlier is not None and self.corner_view is not None:
            vo = np.asarray(self.view_outlier, bool).ravel()
            bad = bad | vo[np.clip(np.asarray(self.corner_view, int).ravel(), 0, vo.size - 1)]
        return r[~bad]


def intrinsics_data(arrays: dict, meta: dict, camera: Camera, rms_px: float | None = None) -> IntrinsicsData:
    """An ``intrinsics/<camera>`` session (:class:`IntrinsicsSession`) arranged for the figures. ``camera`` (the
    bundle's) is used when the session does not carry its own K / dist / image_size."""
    s = IntrinsicsSession.from_parts(arrays, meta)
    res = s.residuals
    d = IntrinsicsData(camera=camera, uv=s.corners_uv, residual=res)
    if s.corner_view is not None:
        # names/status of every input; view_index = the solved views' input index; corner_view = solved-view index per
        # corner; inliers per corner; view_used / view_rms_px per solved view
        d.corner_view = np.asarray(s.corner_view, int)
        all_names = str_list(s.names)
        vi = np.asarray(s.view_index if s.view_index is not None else np.arange(int(np.max(d.corner_view, initial=-1)) + 1), int).ravel()
        d.view_files = [all_names[i] if 0 <= i < len(all_names) else "" for i in vi]
        d.view_names = [Path(f).name if f else f"view {i}" for f, i in zip(d.view_files, vi)]
        d.view_error = s.view_rms_px
        d.view_error_label = "RMS of inlier residuals (px)"
        d.view_outlier = None if s.view_used is None else ~np.asarray(s.view_used, bool)
        if d.view_error is not None and d.view_outlier is not None and res is not None and d.view_outlier.any():
            # a rejected view's inlier RMS hides why it was rejected: show the RMS over all its corners
            r2 = np.sum(np.asarray(res, float).reshape(-1, 2) ** 2, axis=1)
            ok = np.isfinite(r2)
            n = d.view_outlier.size
            rms_all = np.sqrt(np.bincount(d.corner_view[ok], r2[ok], n) / np.maximum(np.bincount(d.corner_view[ok], None, n), 1))
            d.view_error = np.where(d.view_outlier, rms_all, np.asarray(d.view_error, float))
            d.view_error_label = "RMS residual (px; rejected views: all corners)"
        d.corner_outlier = None if s.inliers is None else ~np.asarray(s.inliers, bool)
        d.rejected = [[Path(n).name, st] for n, st in zip(all_names, str_list(s.status)) if st != "used"]
    if d.view_error is not None and len(d.view_names) != np.size(d.view_error):
        d.view_names = [f"view {i}" for i in range(np.size(d.view_error))]
    if s.K is not None and s.dist is not None and s.image_size is not None:  # the camera this session was solved for
        try:
            d.camera = Camera(tuple(int(x) for x in np.asarray(s.image_size).ravel()[:2]), s.K, s.dist, s.camera_model or camera.model)
        except ValueError:
            pass
    d.noise_px = s.noise_px
    d.rms_px = s.rms_px if s.rms_px is not None else rms_px
    d.sigma_u, d.sigma_v, d.sigma_px = s.uncertainty_u, s.uncertainty_v, s.uncertainty_sigma_px
    d.valid_threshold_px = float(s.uncertainty_threshold_px if s.uncertainty_threshold_px is not None else d.noise_px or 1.0)
    d.cv_u, d.cv_v, d.cv_diff_px, d.cv_sigma_px = s.crossval_u, s.crossval_v, s.crossval_diff_px, s.crossval_sigma_px
    d.warnings = [str(w) for w in s.warnings or []]
    return d


def intrinsics_section(camera_name: str, camera: Camera, arrays: dict, meta: dict, entry=None, image: np.ndarray | None = None, skipped: list[str] | None = None, base: Path | list[Path] | None = None) -> Section:
    """Every intrinsics figure the session allows."""
    sec = Section(f"Intrinsics: {camera_name}")
    add = FigureAdder(sec, skipped if skipped is not None else [])
    d = intrinsics_data(arrays, meta, camera, entry.rms_px if entry is not None else None)
    size = d.camera.image_size
    if entry is not None:
        sec.add(camera_param_table(camera_name, entry))
    if d.rejected:
        sec.add(Table(["input", "why not used"], d.rejected, caption=f"{len(d.rejected)} input(s) not used"))
    for w in d.warnings:
        sec.add(f"warning: {w}")
    add("per-view error", lambda: ri.per_view_error_figure(d.view_names, d.view_error, d.view_outlier, None, d.rms_px, ylabel=d.view_error_label), {"per-view errors": d.view_error})
    add("residual vectors", lambda: ri.residual_vectors_figure(d.uv, d.residual, size, image=image, outlier=d.corner_outlier, title="Residual vectors, all views"), {"corner pixels": d.uv, "residuals": d.residual})
    _worst_view_with_image(sec, add.skipped, d, size, base)
    add("residual histogram", lambda: ri.residual_histogram_figure(d.inlier_residuals(), d.noise_px, title="Residuals (inliers) against the expected noise"), {"residuals": d.residual})
    add("coverage", lambda: ri.coverage_figure(d.uv, size), {"corner pixels": d.uv})
    add("projection uncertainty", lambda: ri.uncertainty_map_figure(d.sigma_u, d.sigma_v, d.sigma_px, size, d.valid_threshold_px, d.uv), {"uncertainty grid": d.sigma_px, "grid u": d.sigma_u, "grid v": d.sigma_v})
    add("distortion field", lambda: ri.distortion_figure(d.camera))
    add("cross-validation", lambda: ri.crossval_difference_figure(d.cv_u, d.cv_v, d.cv_diff_px, size, d.cv_sigma_px), {"cross-validation difference": d.cv_diff_px, "grid u": d.cv_u, "grid v": d.cv_v})
    return sec


def _worst_view_with_image(sec: Section, skipped: list[str], d: IntrinsicsData, size: tuple[int, int], base) -> None:
    """Residual vectors over the image of the worst kept view; when its file is gone, over the worst kept view whose
    image is still there (said in the title and as a note); nothing but a note when no image is found."""
    if d.view_error is None or d.corner_view is None or d.uv is None or d.residual is None or not d.view_files:
        return
    e = np.asarray(d.view_error, float).copy()
    kept = np.ones(e.size, bool) if d.view_outlier is None or np.all(d.view_outlier) else ~np.asarray(d.view_outlier, bool)
    order = [int(k) for k in np.argsort(-np.where(np.isfinite(e) & kept, e, -np.inf), kind="stable") if kept[k] and k < len(d.view_files)]
    for rank, k in enumerate(order):
        img = read_image_file(d.view_files[k], base)
        if img is None:
            continue
        m = d.view_mask(k)
        which = "the worst kept view" if rank == 0 else f"the worst kept view with its image on disk ({rank} worse without)"
        if rank:
            skipped.append(f"{sec.title}: residual vectors over {d.view_names[order[0]]} (the worst kept view) drawn over {d.view_names[k]} instead (image not found)")
            sec.add(f"residual vectors over the worst kept view ({d.view_names[order[0]]}): its image is not found; drawn over {d.view_names[k]}, the worst kept view whose image is.")
        sec.add(ri.residual_vectors_figure(np.asarray(d.uv)[m], np.asarray(d.residual)[m], size, image=img, outlier=None if d.corner_outlier is None else np.asarray(d.corner_outlier)[m],
                                           title=f"Residual vectors on {which}, {d.view_names[k]}"))  # fmt: skip
        return
    if order:
        skipped.append(f"{sec.title}: residual vectors over a view's image skipped (no image of the kept views found next to the session or the bundle)")
        sec.add("residual vectors over a view's image: not drawn (no image of the kept views is found next to the session file or the bundle).")


def stereo_section(key: str, arrays: dict, meta: dict, skipped: list[str] | None = None) -> Section:
    """``stereo/<cam0>_<cam1>`` (``radarcal intrinsics --right``): per-pair RMS in both cameras and the residuals."""
    sec = Section(f"Stereo: {key.split('/', 1)[-1]}")
    add = FigureAdder(sec, skipped if skipped is not None else [])
    s = StereoSession.from_parts(arrays, meta, key)
    r0, r1, pair = s.residuals0, s.residuals1, s.pair_of_corner
    inl = None if s.inliers is None else np.asarray(s.inliers, bool).ravel()
    names = [" / ".join(Path(str(x)).name for x in np.atleast_1d(row)) for row in np.asarray(s.pair_names if s.pair_names is not None else np.zeros((0, 2), str))]

    def per_pair() -> Any:
        p = np.asarray(pair, int).ravel()
        n = max(len(names), int(p.max()) + 1 if p.size else 0)
        m = np.ones(p.size, bool) if inl is None else inl
        r2 = np.sum(np.asarray(r0, float) ** 2, axis=1) + np.sum(np.asarray(r1, float) ** 2, axis=1)
        rms = np.sqrt(np.bincount(p[m], r2[m] / 2, n) / np.maximum(np.bincount(p[m], None, n), 1))
        labels = names if len(names) == n else [f"pair {i}" for i in range(n)]
        return ri.per_view_error_figure(labels, rms, None, title="Stereo: RMS per pair (both cameras)", ylabel="RMS residual (px)")

    add("per-pair error", per_pair, {"residuals0": r0, "residuals1": r1, "pair_of_corner": pair})
    add("stereo residual histogram", lambda: ri.residual_histogram_figure(np.r_[np.asarray(r0)[inl if inl is not None else slice(None)], np.asarray(r1)[inl if inl is not None else slice(None)]], title="Stereo residuals (both cameras, inliers)"), {"residuals0": r0, "residuals1": r1})
    return sec

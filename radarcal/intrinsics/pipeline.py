"""From detections to a camera: view screening (size, blur, novelty), solve with rejection, cross-validation,
uncertainty map. Pure numeric core behind ``radarcal intrinsics`` (the CLI reads files and prints)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from radarcal.board import BoardSpec, object_points
from radarcal.intrinsics.crossval import CrossValidation, ModelChoice, choose_model, cross_validate
from radarcal.intrinsics.detect import Detection
from radarcal.intrinsics.select import Coverage, coverage, novel_mask, view_descriptor
from radarcal.intrinsics.solve import MODELS, Calibration, SolveError, UncertaintyMap, calibrate, projection_uncertainty

__all__ = ["IntrinsicsResult", "NotEnoughViews", "run_intrinsics", "screen_views"]


class NotEnoughViews(SolveError):
    """Fewer than 3 usable views."""


@dataclass
class IntrinsicsResult:
    calibration: Calibration
    names: list[str]  # all inputs, in order
    status: list[str]  # per input: "used", or the rejection reason
    view_index: list[int]  # input index of each solver view (calibration.residuals[k] belongs to names[view_index[k]])
    detections: list[Detection | None]
    descriptors: np.ndarray  # (V,4) of the solver views
    coverage: Coverage
    uncertainty: UncertaintyMap
    crossval: CrossValidation | None
    model_choice: ModelChoice | None
    board: BoardSpec
    warnings: list[str] = field(default_factory=list)

    @property
    def camera(self):
        return self.calibration.camera


def screen_views(names: list[str], detections: list[Detection | None], errors: list[str], board: BoardSpec, blur_factor: float = 2.0, blur_min_px: float = 3.5, novelty: float = 0.0) -> tuple[list[int], list[str]]:
    """Which inputs go to the solver, and a status per input (``"used"`` or why not)."""
    status = ["" for _ in names]
    cand = []
    for i, (d, e) in enumerate(zip(detections, errors)):
        if d is None:
            status[i] = e or "unreadable"
        elif not d.ok:
            status[i] = d.reason or "no board"
        else:
            cand.append(i)
    if cand:
        size = Counter(tuple(detections[i].image_size) for i in cand).most_common(1)[0][0]
        for i in list(cand):
            if tuple(detections[i].image_size) != size:
                w, h = detections[i].image_size
                status[i] = f"image size {w}x{h} differs from the set's {size[0]}x{size[1]}"
                cand.remove(i)
    if cand:
        widths = np.array([detections[i].edge_width_px for i in cand])
        med = float(np.nanmedian(widths)) if np.any(np.isfinite(widths)) else np.nan
        limit = max(blur_factor * med, blur_min_px) if np.isfinite(med) else np.inf
        for i, wdt in zip(list(cand), widths):
            if np.isfinite(wdt) and wdt > limit:
                status[i] = f"blurred (edge width {wdt:.1f} px > {limit:.1f} px)"
                cand.remove(i)
    if cand and novelty > 0:
        descs = np.array([view_descriptor(detections[i].uv, detections[i].ids, board.grid_shape, detections[i].image_size) for i in cand])
        keep = novel_mask(descs, novelty)
        for i, k in zip(list(cand), keep):
            if not k:
                status[i] = f"not novel (X/Y/Size/Skew within {novelty} of an earlier view)"
                cand.remove(i)
    for i in cand:
        status[i] = "used"
    return cand, status


def run_intrinsics(
    names: list[str],
    detections: list[Detection | None],
    board: BoardSpec,
    errors: list[str] | None = None,
    model: str = "pinhole5",
    crossval: bool = True,
    novelty: float = 0.0,
    reject: bool = True,
    k_sigma: float = 4.0,
    grid_nx: int = 40,
) -> IntrinsicsResult:
    """Screen the views, solve (``model`` one of MODELS or ``"auto"``), cross-validate, map the uncertainty."""
    errors = errors or [""] * len(names)
    cand, status = screen_views(names, detections, errors, board, novelty=novelty)
    if len(cand) < 3:
        raise NotEnoughViews(f"only {len(cand)} usable views (need 3)")
    obj_all = object_points(board)
    obj = [obj_all[detections[i].ids] for i in cand]
    img = [detections[i].uv for i in cand]
    size = detections[cand[0]].image_size
    choice = None
    cv = None
    notes: list[str] = []
    if model == "auto":
        choice, cals, cvs = choose_model(obj, img, size, MODELS, reject=reject, k_sigma=k_sigma)
        cal = cals[choice.model]
        cv = cvs.get(choice.model)
    else:
        if model not in MODELS:
            raise ValueError(f"model must be auto or one of {MODELS}")
        cal = calibrate(obj, img, size, model, reject=reject, k_sigma=k_sigma)
        if crossval and len(cand) >= 6:
            try:
                cv = cross_validate(obj, img, size, model, reject=reject, k_sigma=k_sigma)
            except (SolveError, np.linalg.LinAlgError) as e:  # a half can be degenerate; not fatal
                notes.append(f"cross-validation failed: {e}")
    for k, i in enumerate(cand):
        if not cal.view_used[k]:
            status[i] = cal.view_reasons[k]
    unc = projection_uncertainty(cal, nx=grid_nx)
    descs = np.array([view_descriptor(detections[i].uv, detections[i].ids, board.grid_shape, size) for i in cand])
    used = cal.view_used
    uv_used = np.concatenate([img[k][cal.inliers[k]] for k in np.flatnonzero(used)])
    cov = coverage(descs[used], uv_used, size)
    warnings = notes + list(cov.warnings)
    if cv is not None and not cv.consistent:
        warnings.append(
            f"cross-validation: the two halves of the views differ by {cv.diff_median_px:.2f} px (median over the image), "
            f"{cv.ratio_median:.1f}x their uncertainty {cv.sigma_median_px:.2f} px: the data are inconsistent (moving focus, "
            f"board not flat, rolling shutter, wrong model?)"
        )
    if cal.view_used.sum() < 10:
        warnings.append(f"only {int(cal.view_used.sum())} views used: 15-30 well spread views are recommended")
    return IntrinsicsResult(cal, list(names), status, cand, list(detections), descs, cov, unc, cv, choice, board, warnings)

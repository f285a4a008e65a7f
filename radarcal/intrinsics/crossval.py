"""Cross-validation of an intrinsics solve and automatic model choice.

The views are split into two interleaved halves; each half is calibrated alone. The two models are compared the way
mrcal's ``projection_diff`` does: grid pixels are unprojected with half A, the best rotation between the halves'
rays is fitted (weighted by 1/σ²; a small common rotation is not an intrinsics difference) and the rays are
projected with half B. The difference is compared with σ_diff = sqrt(σ_A² + σ_B²) from
:func:`~radarcal.intrinsics.solve.projection_uncertainty`. The halves are *consistent* when the median of
diff/σ_diff is below ``ratio_limit`` (≈ 1.2 is expected from noise alone).

``choose_model``: the simplest model whose RMS is within 10 % of the best one and whose halves are consistent
(guards against both under-fitting and rational-model over-fitting).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radarcal.intrinsics._blas import single_thread_blas
from radarcal.intrinsics.solve import Calibration, SolveError, calibrate, projection_uncertainty

__all__ = ["CrossValidation", "ModelChoice", "split_halves", "projection_difference", "cross_validate", "choose_model"]

_COMPLEXITY = {"pinhole5": 0, "fisheye": 1, "pinhole8": 2}


@dataclass
class CrossValidation:
    model: str
    half_a: Calibration
    half_b: Calibration
    u: np.ndarray
    v: np.ndarray
    diff_px: np.ndarray  # (ny,nx)
    sigma_px: np.ndarray  # (ny,nx) σ of the difference
    ratio_median: float
    diff_median_px: float
    sigma_median_px: float
    consistent: bool

    def summary(self) -> dict:
        return {
            "model": self.model,
            "diff_median_px": self.diff_median_px,
            "diff_max_px": float(np.nanmax(self.diff_px)),
            "sigma_median_px": self.sigma_median_px,
            "ratio_median": self.ratio_median,
            "consistent": self.consistent,
            "fx": [self.half_a.camera.fx, self.half_b.camera.fx],
            "cx": [self.half_a.camera.cx, self.half_b.camera.cx],
            "cy": [self.half_a.camera.cy, self.half_b.camera.cy],
        }


@dataclass
class ModelChoice:
    model: str
    table: list[dict] = field(default_factory=list)  # per candidate: model, rms_px, cross-validation summary / error
    reason: str = ""


def split_halves(n_views: int) -> tuple[np.ndarray, np.ndarray]:
    """Interleaved halves (even / odd views): both halves see the whole session."""
    idx = np.arange(n_views)
    return idx[0::2], idx[1::2]


def _kabsch(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Rotation R minimising Σ w |R a − b|²."""
    H = (a * w[:, None]).T @ b
    U, _S, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def projection_difference(cam_a, cam_b, u: np.ndarray, v: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """|q − project_B(R · unproject_A(q))| on the grid (ny,nx), R the fitted implied rotation."""
    q = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    ra = cam_a.unproject(q)
    rb = cam_b.unproject(q)
    w = np.ones(len(q)) if weights is None else np.asarray(weights, float).ravel()
    ok = np.all(np.isfinite(ra), axis=1) & np.all(np.isfinite(rb), axis=1) & np.isfinite(w)
    R = _kabsch(ra[ok], rb[ok], w[ok])
    qb, valid = cam_b.project(ra @ R.T)
    d = np.linalg.norm(qb - q, axis=1)
    d[~valid] = np.nan
    return d.reshape(len(v), len(u))


@single_thread_blas
def cross_validate(object_points, image_points, image_size, model: str, nx: int = 30, ratio_limit: float = 2.5, **calib_kw) -> CrossValidation:
    ia, ib = split_halves(len(object_points))
    cal_a = calibrate([object_points[i] for i in ia], [image_points[i] for i in ia], image_size, model, **calib_kw)
    cal_b = calibrate([object_points[i] for i in ib], [image_points[i] for i in ib], image_size, model, **calib_kw)
    ua = projection_uncertainty(cal_a, nx=nx)
    ub = projection_uncertainty(cal_b, nx=nx)
    sig = np.sqrt(ua.sigma_px**2 + ub.sigma_px**2)
    diff = projection_difference(cal_a.camera, cal_b.camera, ua.u, ua.v, 1.0 / np.maximum(sig, 1e-6) ** 2)
    ratio = diff / np.maximum(sig, 1e-9)
    rmed = float(np.nanmedian(ratio))
    return CrossValidation(model, cal_a, cal_b, ua.u, ua.v, diff, sig, rmed, float(np.nanmedian(diff)), float(np.nanmedian(sig)), bool(rmed < ratio_limit))


@single_thread_blas
def choose_model(object_points, image_points, image_size, candidates=("pinhole5", "pinhole8", "fisheye"), rms_slack: float = 0.10, **kw) -> tuple[ModelChoice, dict[str, Calibration], dict[str, CrossValidation]]:
    """Try each candidate (full solve + cross-validation) and pick the simplest adequate one (see module doc)."""
    cals: dict[str, Calibration] = {}
    cvs: dict[str, CrossValidation] = {}
    table = []
    for m in sorted(candidates, key=lambda m: _COMPLEXITY[m]):
        row = {"model": m}
        try:
            cals[m] = calibrate(object_points, image_points, image_size, m, **kw)
            row["rms_px"] = cals[m].rms_px
            cvs[m] = cross_validate(object_points, image_points, image_size, m, **kw)  # kw: calibrate() options
            row.update({k: v for k, v in cvs[m].summary().items() if k != "model"})
        except (SolveError, np.linalg.LinAlgError, ValueError) as e:
            row["error"] = str(e)
        table.append(row)
    if not cals:
        raise SolveError("no camera model could be solved: " + "; ".join(r.get("error", "") for r in table))
    best_rms = min(c.rms_px for c in cals.values())
    fit = [m for m in cals if cals[m].rms_px <= best_rms * (1 + rms_slack) + 1e-3]
    for row in table:
        row["fits"] = row["model"] in fit
    fit.sort(key=lambda m: _COMPLEXITY[m])
    good = [m for m in fit if m in cvs and cvs[m].consistent]
    if good:
        return ModelChoice(good[0], table, f"simplest model with RMS within {rms_slack:.0%} of the best and consistent halves"), cals, cvs
    with_cv = [m for m in fit if m in cvs] or fit
    m = min(with_cv, key=lambda m: cvs[m].ratio_median if m in cvs else np.inf)
    return ModelChoice(m, table, "no model has consistent halves: picked the least inconsistent (check the data)"), cals, cvs

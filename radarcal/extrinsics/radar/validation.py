"""Leave-one-out cross-validation and outlier rejection of a 2D radar fit."""

from __future__ import annotations

import numpy as np

from radarcal.extrinsics.radar.geometry2d import fit_rigid_2d, slant_predict
from radarcal.extrinsics.radar.geometry2d import wrap_angle as _wrap

__all__ = ["leave_one_out", "reject_outliers"]


def leave_one_out(src: np.ndarray, dst: np.ndarray, **fit_kw) -> dict:
    """Refit without each correspondence in turn: its prediction error (hold-out residual), the parameter spread
    and the jackknife standard errors of (theta, a, b)."""
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    n = len(src)
    min_n = 3 if fit_kw.get("estimate_height") else 2
    if n <= min_n:
        return {"n": n, "holdout_residuals": np.full(n, np.nan), "holdout_rms": float("nan"), "params": np.zeros((0, 3)), "jackknife_sigma": {}}
    z = fit_kw.pop("src_z", None)
    w = fit_kw.pop("weights", None)
    w = None if w is None else np.asarray(w, float)
    res = np.zeros(n)
    params = np.zeros((n, 3))
    for i in range(n):  # loop over reflectors (few)
        m = np.arange(n) != i
        f = fit_rigid_2d(src[m], dst[m], src_z=None if z is None else np.asarray(z)[m], weights=None if w is None else w[m], **fit_kw)
        q = f.pose.apply(src[i:i + 1])
        pred = q if z is None else slant_predict(q, np.asarray(z)[i] - f.height)
        res[i] = float(np.linalg.norm(pred[0] - dst[i]))
        params[i] = f.pose.as_array()
    params[:, 0] = params[0, 0] + _wrap(params[:, 0] - params[0, 0])
    jk = np.sqrt((n - 1) / n * np.sum((params - params.mean(axis=0)) ** 2, axis=0))
    return {"n": n, "holdout_residuals": res, "holdout_rms": float(np.sqrt(np.mean(res**2))), "params": params,
            "std": {"theta": float(params[:, 0].std()), "a": float(params[:, 1].std()), "b": float(params[:, 2].std())},
            "jackknife_sigma": {"theta": float(jk[0]), "a": float(jk[1]), "b": float(jk[2])}}


def reject_outliers(src: np.ndarray, dst: np.ndarray, threshold: float = 0.15, min_keep: int = 3, k_sigma: float = 4.0, **fit_kw) -> tuple[np.ndarray, list]:
    """Iteratively drop the most significant correspondence -- of those whose leave-one-out residual (leverage formula)
    exceeds ``threshold`` (m), the largest studentised one (weighted, its leverage's variance inflation
    ``(I - H_jj)^-1`` removed; not one whose leverage's trace is 1 or more) -- while its exact hold-out residual (a refit without it) stays beyond ``threshold`` and,
    studentised, beyond ``k_sigma`` (small-sample corrected) times the robust unit-weight sigma of the fit without it.
    Returns (keep mask, [(index, reason)])."""
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    keep = np.ones(len(src), bool)
    reasons = []
    z = fit_kw.pop("src_z", None)
    zz = None if z is None else np.asarray(z, float)
    w = fit_kw.pop("weights", None)
    w = np.ones(len(src)) if w is None else np.asarray(w, float)
    n_par = 4 if fit_kw.get("estimate_height") else 3
    while keep.sum() > max(min_keep, 2) and 2 * (keep.sum() - 1) > n_par:
        idx = np.nonzero(keep)[0]
        f = fit_rigid_2d(src[idx], dst[idx], src_z=None if zz is None else zz[idx], weights=w[idx], **fit_kw)
        if f.rms <= threshold / k_sigma / 4:
            break  # everything already fits far below the threshold
        d, M, ok = f.deletion_residuals()
        # the candidate: the most significant (studentised, weighted) of those beyond ``threshold`` in metres -- not the
        # largest in metres, which is often a weak echo well within its own noise and would end the search; a point
        # that alone fixes a direction of the fit (leverage 1) cannot be tested, nor one that carries a whole
        # parameter's worth of the information (trace of its leverage >= 1: one of a radar's two strong echoes among
        # weak ones -- the others neither predict it nor give a noise scale that applies to it)
        stat = w[idx] * np.einsum("ni,nij,nj->n", d, M, d)
        cand = ok & (np.linalg.norm(d, axis=1) > threshold) & (np.trace(M, axis1=1, axis2=2) > 1.0)  # trace(I - H) > 1: trace(H) < 1
        if not cand.any():
            break
        j = int(np.argmax(np.where(cand, stat, -1.0)))
        rest = np.delete(idx, j)
        g = fit_rigid_2d(src[rest], dst[rest], src_z=None if zz is None else zz[rest], init=f.pose, weights=w[rest], **fit_kw)
        q = g.pose.apply(src[idx[j]][None])
        pred = q if zz is None else slant_predict(q, zz[idx[j]] - g.height)
        e = pred[0] - dst[idx[j]]
        rj = float(np.linalg.norm(e))
        unit = np.sqrt(w[rest]) * np.linalg.norm(g.residuals, axis=1)
        dof = max(2 * len(rest) - n_par, 1)
        # robust unit-weight sigma of the others (median 2D residual length = 1.177 sigma, corrected for the fitted
        # parameters): weak outliers among them must not hide this one (their RMS would)
        scale = float(np.median(unit) / 1.177 * np.sqrt(2 * len(rest) / dof))
        # studentised: the others' fit predicts a far, isolated correspondence (high leverage) poorly, so its deletion
        # residual's variance is sigma^2 / w (I - H_jj)^-1, not sigma^2 / w
        rj_std = float(np.sqrt(max(w[idx[j]] * e @ M[j] @ e, 0.0)))
        k_eff = _small_sample_k(k_sigma, dof)
        if rj > threshold and rj_std > k_eff * scale:
            keep[idx[j]] = False
            reasons.append((int(idx[j]), f"hold-out residual {rj:.3f} m > {threshold:g} m and {rj_std / max(scale, 1e-12):.1f} sigma of the others' fit (> {k_eff:.2g}, leverage removed)"))
        else:
            break
    return keep, reasons


def _small_sample_k(k_sigma: float, dof: int) -> float:
    """Threshold on a 2D residual's length in sigma when sigma itself comes from ``dof`` residual degrees of freedom:
    the same false-rejection rate as ``k_sigma`` with a known sigma (chi-square, 2 dof: ``exp(-k^2/2)``), from
    ``2 F(2, dof)`` (a few matches estimate sigma poorly: 3 sigma becomes 5.0 at 5 dof, 3.1 at 50)."""
    from scipy.stats import f as f_dist

    return float(np.sqrt(2.0 * f_dist.isf(np.exp(-k_sigma**2 / 2), 2, max(dof, 1))))

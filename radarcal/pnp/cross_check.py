"""How well two cameras agree on the same field point (``bundle show``, ``field-pnp``, ``bundle validate``, ``run``).

Two cameras A and B with field poses of their own (``T_A_field``, ``T_B_field``, e.g. ``field-pnp`` on each) and a
link between them that does not go through the field (``T_B_A``: the stereo pair, or both LiDAR extrinsics
``T_B_lidar0 · T_lidar0_A``) form a loop; with perfect calibrations it closes. :func:`pair_agreement` measures what
the loop's mismatch does to localisation, on points of the field surface both cameras see:

* **cm**: a point ``p`` that A sees is, through the link, a 3D point in B's frame (what LiDAR depth gives B); B's
  field pose puts it at ``T_field_B · T_B_A · T_A_field · p``. The horizontal distance to ``p`` (and the same from B
  to A) is the disagreement of the two cameras' field positions for the same robot, in cm.
* **px**: where B's field pose projects ``p`` versus where the link puts the point A sees (and the same in A's image).

:func:`bundle_cross_checks` finds the pairs in a bundle and says why a pair cannot be checked (no field pose of its
own, no link besides the field). The disagreement the calibrations' own σ explain is predicted from the field poses'
covariances (field-pnp's session) and the link entries' σ; a pair whose median disagreement exceeds ``k_sigma`` times
that (and a floor of ``flag_cm`` / ``flag_px``) is flagged: ``bundle validate``, the report and ``run`` list it
(:func:`cross_check_flags`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera

__all__ = ["CrossCheckOptions", "PairAgreement", "pair_agreement", "bundle_cross_checks", "cross_check_flags", "format_agreement"]


@dataclass
class CrossCheckOptions:
    step_m: float = 0.5  # grid of surface points over the field
    max_range_m: float = 45.0  # points farther than this from a camera are not used
    target_height_m: float = 0.3  # above the surface (armour height): what the runtime localises
    k_sigma: float = 3.0  # flagged when the median disagreement exceeds k x the one the calibrations' own σ predict ...
    flag_cm: float = 5.0  # ... and this floor (cm, horizontal) ...
    flag_px: float = 3.0  # ... or, in either image, k x the predicted pixel disagreement and this floor (px)
    min_points: int = 20  # fewer shared points than this: too little overlap to judge


def _stats(v: np.ndarray) -> dict:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    if not len(v):
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan"), "n": 0}
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max()), "n": int(len(v))}


@dataclass
class PairAgreement:
    """Disagreement of cameras ``a`` and ``b`` on the same field points (cm horizontal; px in each image)."""

    camera_a: str
    camera_b: str
    link: str = ""  # how T_b_a is known without the field, e.g. "T_cam1_lidar0 · T_cam0_lidar0"
    n_points: int = 0  # surface points both cameras see
    cm: dict = field(default_factory=dict)  # horizontal disagreement: median, p95, max (cm), n
    px_a: dict = field(default_factory=dict)  # in a's image (px)
    px_b: dict = field(default_factory=dict)  # in b's image (px)
    landmarks: dict = field(default_factory=dict)  # name -> {"cm", "px_a", "px_b"} for landmarks both see
    expected_cm: float = float("nan")  # median 1σ disagreement predicted from the poses' and the link's σ
    expected_px: tuple = (float("nan"), float("nan"))  # the same in a's and b's image
    flagged: bool = False
    note: str = ""  # why the pair was not compared, or why it is flagged

    @property
    def compared(self) -> bool:
        return self.n_points > 0


def _visible(cam: Camera, T_cam_field: np.ndarray, P: np.ndarray, max_range: float, field_model) -> np.ndarray:
    uv, valid, z = cam.project_from(T_cam_field, P)
    ok = valid & cam.in_image(uv) & (z < max_range)
    if field_model is not None and np.any(ok):
        from radarcal.pnp.error_map import ground_visible

        idx = np.flatnonzero(ok)
        ok[idx] = ground_visible(field_model, geometry.invert_T(T_cam_field)[:3, 3], P[idx], tol=0.1)
    return ok


def _one_way(cam_b: Camera, T_a_field, T_b_field, T_b_a, P):
    """Points P (N,3) as A sees them, carried into B by the link: B's field position error (N,) m horizontal and
    the pixel offset in B (N,) against B's own projection of P."""
    p_b = geometry.transform_points(T_b_a @ T_a_field, P)
    q = geometry.transform_points(geometry.invert_T(T_b_field), p_b)
    uv_link, ok1 = cam_b.project(p_b)
    uv_own, ok2, _ = cam_b.project_from(T_b_field, P)
    px = np.where(ok1 & ok2, np.linalg.norm(uv_link - uv_own, axis=1), np.nan)
    return np.linalg.norm(q[:, :2] - P[:, :2], axis=1), px


def _predicted_cm(cam_a, cam_b, T_a_field, T_b_field, cov_a, cov_b, link_sigma, P) -> np.ndarray:
    """(N,) predicted 1σ horizontal disagreement (cm) at P: both field poses' covariances (6x6 over [rotvec, t], the
    LiDAR-depth localisation error they cause) and each link entry's (rotation rad, translation m) σ at the distance."""
    from radarcal.pnp.error_map import localisation_sigma

    var = np.zeros(len(P))
    for cam, T, cov in ((cam_a, T_a_field, cov_a), (cam_b, T_b_field, cov_b)):
        if cov is not None:
            var += np.nan_to_num(localisation_sigma(cam, T, cov, P, pixel_sigma=0.0, range_sigma=0.0, mode="lidar")) ** 2
    d = np.linalg.norm(geometry.transform_points(T_a_field, P), axis=1)
    for rot, trans in link_sigma:
        var += (d * rot) ** 2 + trans**2
    return 100 * np.sqrt(var)


def pair_agreement(cam_a: Camera, cam_b: Camera, T_a_field: np.ndarray, T_b_field: np.ndarray, T_b_a: np.ndarray, field_model,
                   options: CrossCheckOptions | None = None, names: tuple[str, str] = ("a", "b"), link: str = "",
                   cov_a: np.ndarray | None = None, cov_b: np.ndarray | None = None, link_sigma: tuple = ()) -> PairAgreement:
    """Disagreement on the field points both cameras see (module docstring). Frames: ``T_x_field`` maps field points
    (m) into camera x; ``T_b_a`` maps camera a into camera b. ``cov_a`` / ``cov_b``: 6x6 covariances of the field
    poses ([rotvec, t] of ``T_x_field``), ``link_sigma``: (rotation σ rad, translation σ m) per entry of the link; from
    them the disagreement the calibrations' own noise explains (the flag compares against it). Pure numpy."""
    o = options or CrossCheckOptions()
    L, W = field_model.size
    X, Y = np.meshgrid(np.arange(o.step_m / 2, L, o.step_m), np.arange(o.step_m / 2, W, o.step_m))
    xy = np.stack([X.ravel(), Y.ravel()], 1)
    P = np.column_stack([xy, field_model.surface_z(xy) + o.target_height_m])
    both = _visible(cam_a, T_a_field, P, o.max_range_m, field_model) & _visible(cam_b, T_b_field, P, o.max_range_m, field_model)
    P = P[both]
    out = PairAgreement(names[0], names[1], link=link, n_points=int(len(P)))
    if not len(P):
        out.note = "the two views share no field surface"
        return out
    T_a_b = geometry.invert_T(T_b_a)
    cm_ab, px_b = _one_way(cam_b, T_a_field, T_b_field, T_b_a, P)
    cm_ba, px_a = _one_way(cam_a, T_b_field, T_a_field, T_a_b, P)
    out.cm = _stats(100 * np.concatenate([cm_ab, cm_ba]))
    out.px_a, out.px_b = _stats(px_a), _stats(px_b)
    lm_names = sorted(field_model.landmarks)
    if lm_names:
        Q = field_model.landmark_array(lm_names)
        seen = _visible(cam_a, T_a_field, Q, o.max_range_m, None) & _visible(cam_b, T_b_field, Q, o.max_range_m, None)
        if np.any(seen):
            c1, pb = _one_way(cam_b, T_a_field, T_b_field, T_b_a, Q[seen])
            c2, pa = _one_way(cam_a, T_b_field, T_a_field, T_a_b, Q[seen])
            out.landmarks = {n: {"cm": float(50 * (x + y)), "px_a": float(u), "px_b": float(v)} for n, x, y, u, v in zip(np.array(lm_names)[seen], c1, c2, pa, pb)}
    if len(P) < o.min_points:
        out.note = f"only {len(P)} shared field points: too little overlap to judge"
        return out
    pred = _predicted_cm(cam_a, cam_b, T_a_field, T_b_field, cov_a, cov_b, link_sigma, P)
    out.expected_cm = float(np.median(pred))
    out.expected_px = tuple(float(np.median(pred / 100 / cam.project_from(T, P)[2] * cam.fx)) for cam, T in ((cam_a, T_a_field), (cam_b, T_b_field)))
    why = []
    lim_cm = max(o.flag_cm, o.k_sigma * out.expected_cm)
    if out.cm["median"] > lim_cm:
        why.append(f"median {out.cm['median']:.1f} cm > {lim_cm:.1f} cm")
    for cam, st, e in ((names[0], out.px_a, out.expected_px[0]), (names[1], out.px_b, out.expected_px[1])):
        lim_px = max(o.flag_px, o.k_sigma * e)
        if st["median"] > lim_px:
            why.append(f"median {st['median']:.1f} px > {lim_px:.1f} px in {cam}")
    if why:
        out.flagged = True
        out.note = "the cameras disagree: " + ", ".join(why) + f" (one of T_{names[0]}_field, T_{names[1]}_field, {link} is wrong)"
    return out


def _entry_sigma(entry) -> tuple[float, float]:
    """(rotation σ rad, translation σ m) of a stored transform from whichever σ its command wrote (0, 0: none)."""
    s = entry.sigma or {}
    for rk, tk in (("edge_bootstrap_rot_deg", "edge_bootstrap_trans_m"), ("edge_rot_deg", "edge_trans_m"), ("pnp_rot_deg", "pnp_trans_m"), ("rot_deg", "trans_m")):
        if rk in s and tk in s:
            r, t = np.radians(np.asarray(s[rk], float)), np.asarray(s[tk], float)
            if np.all(np.isfinite(r)) and np.all(np.isfinite(t)):
                return float(np.linalg.norm(r)), float(np.linalg.norm(t))
    if all(k in s for k in ("rx", "ry", "rz", "tx", "ty", "tz")):  # the stereo pair (radians, metres)
        return float(np.linalg.norm([s["rx"], s["ry"], s["rz"]])), float(np.linalg.norm([s["tx"], s["ty"], s["tz"]]))
    return 0.0, 0.0


def _field_pose_cov(bundle, camera: str, T_cam_field: np.ndarray, entry) -> np.ndarray | None:
    """6x6 covariance of ``T_<camera>_field`` ([rotvec, t]): field-pnp's session when it holds this very pose, else a
    diagonal from the entry's σ (rot_deg, t_m), else None."""
    from radarcal.errors import InputError

    if f"field_pnp/{camera}" in bundle.sessions and bundle.path is not None:
        try:
            from radarcal.bundle import load_session

            arrays, _ = load_session(bundle, f"field_pnp/{camera}")
            if "cov_pose" in arrays and np.allclose(arrays["T_cam_field"], T_cam_field, atol=1e-9):
                return np.asarray(arrays["cov_pose"], float)
        except InputError:
            pass  # a missing / unreadable session: fall back to the entry's σ
    s = entry.sigma or {}
    if "rot_deg" in s and "t_m" in s:
        return np.diag(np.concatenate([np.radians(np.asarray(s["rot_deg"], float)), np.asarray(s["t_m"], float)]) ** 2)
    return None


def bundle_cross_checks(bundle, options: CrossCheckOptions | None = None) -> list[PairAgreement]:
    """One :class:`PairAgreement` per camera pair of the bundle (a ``note`` says why a pair was not compared)."""
    from radarcal.extrinsics.lidar_camera_chain import chain, is_derived, own_entry

    cams = sorted(bundle.cameras)
    if len(cams) < 2:
        return []
    fm = bundle.field() if bundle.field_model else None
    out = []
    for a, b in combinations(cams, 2):
        pa = PairAgreement(a, b)
        own = {c: own_entry(bundle, c, "field") for c in (a, b)}
        missing = [c for c in (a, b) if own[c] is None]
        link = chain(bundle, b, a, avoid=("field",))
        if fm is None:
            pa.note = "no field model in the bundle"
        elif missing:
            derived = [c for c in missing if any(is_derived(e) for n, e in bundle.transforms.items() if n in (f"T_{c}_field", f"T_field_{c}"))]
            pa.note = (f"{', '.join(missing)} has no field pose of its own" + (", only one derived through the stereo pair, which agrees by construction" if derived else "")
                       + f"; run `radarcal field-pnp --camera {missing[0]}` to compare")
        elif link is None:
            pa.note = f"no link between {a} and {b} besides the field (no stereo pair, no LiDAR extrinsic of both): nothing to compare"
        else:
            T = {c: own[c].T if own[c].target == c else geometry.invert_T(own[c].T) for c in (a, b)}
            cov = {c: _field_pose_cov(bundle, c, T[c], own[c]) for c in (a, b)}
            pa = pair_agreement(bundle.camera(a), bundle.camera(b), T[a], T[b], link[0], fm, options, (a, b), " · ".join(link[1]),
                                cov[a], cov[b], tuple(_entry_sigma(bundle.transforms[n]) for n in link[1]))
        out.append(pa)
    return out


def format_agreement(p: PairAgreement) -> str:
    """One line for people."""
    if not p.compared or not p.cm:
        return f"{p.camera_a} vs {p.camera_b}: not compared ({p.note})"
    s = (f"{p.camera_a} vs {p.camera_b} on {p.n_points} shared field points (link {p.link}): horizontal disagreement median {p.cm['median']:.1f} cm, "
         f"p95 {p.cm['p95']:.1f} cm, max {p.cm['max']:.1f} cm; median {p.px_a['median']:.2f} px in {p.camera_a}, {p.px_b['median']:.2f} px in {p.camera_b}; "
         f"the calibrations' σ explain {p.expected_cm:.1f} cm")
    return s + (f"  FLAGGED: {p.note}" if p.flagged else f"  ({p.note})" if p.note else "")


def cross_check_flags(bundle, options: CrossCheckOptions | None = None) -> list[str]:
    """One line per flagged camera pair (for :func:`radarcal.verdicts.forced_entries`)."""
    from radarcal.errors import InputError

    try:
        checks = bundle_cross_checks(bundle, options)
    except InputError:  # an invalid field model: `bundle validate` reports it itself
        return []
    return [f"cameras {p.camera_a} and {p.camera_b}: {p.note}; median {p.cm['median']:.1f} cm, p95 {p.cm['p95']:.1f} cm, "
            f"{p.px_a['median']:.1f} px in {p.camera_a}, {p.px_b['median']:.1f} px in {p.camera_b} on {p.n_points} shared field points" for p in checks if p.flagged]

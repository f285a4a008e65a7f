"""The radar(-LiDAR) section of the report, from :class:`radarcal.extrinsics.radar_lidar_session.RadarLidarSession`
files (exactly the names ``radarcal radar-lidar`` writes) and the bundle's ``T_<main>_<sensor>`` entries (pose, σ,
residual summary)."""

from __future__ import annotations

from typing import Any

import numpy as np

from radarcal.extrinsics.radar_lidar_session import RadarLidarSession
from radarcal.report import radar as rr
from radarcal.report.html import Section, Table
from radarcal.report.sections_common import FigureAdder

__all__ = ["radar_lidar_section"]


def _f(v: Any, scale: float = 1.0, fmt: str = ".3g") -> str:
    return "—" if v is None or not np.isfinite(float(v)) else format(float(v) * scale, fmt)


def radar_lidar_section(key: str, arrays: dict, meta: dict, transforms: dict, skipped: list[str] | None = None) -> Section:
    """Every radar figure the session allows; ``transforms``: the bundle's transform entries (``T_<main>_<sensor>``)."""
    s = RadarLidarSession.from_parts(arrays, meta, key)
    main = s.main_lidar or "lidar0"
    sec = Section(f"Radar-LiDAR: {main}")
    add = FigureAdder(sec, skipped if skipped is not None else [])
    radars = s.radars()
    scenes = s.scenes()
    sec.add(f"{len(scenes)} reflector placement(s), {len(radars)} radar(s) ({', '.join(radars) or 'none'}) into {main}; model {s.model or '?'}"
            + (f", reference radar {s.reference_radar}" if s.reference_radar else "") + ".")  # fmt: skip
    for n in s.notes or []:
        sec.add(f"note: {n}")
    q = s.quantisation or {}
    if q.get("note"):
        sec.add(f"quantisation: {q['note']}")
    entries = {r: transforms.get(f"T_{main}_{r}") for r in radars}
    rows = []
    for r in radars:
        e = entries[r]
        res, sig = (e.residual or {}) if e else {}, (e.sigma or {}) if e else {}
        rows.append([f"T_{main}_{r}", _f(res.get("rms_m"), 100, ".2f"), res.get("n", "—"), _f(res.get("holdout_rms_m"), 100, ".2f"), res.get("rejected", "—"),
                     _f(sig.get("yaw_deg"), 1, ".3f"), _f(sig.get("jackknife_yaw_deg"), 1, ".3f"), _f(sig.get("x_m"), 100, ".2f"), _f(sig.get("y_m"), 100, ".2f")])  # fmt: skip
    if rows:
        sec.add(Table(["transform", "RMS (cm)", "n", "hold-out RMS (cm)", "rejected", "σ yaw (deg)", "σ yaw jackknife (deg)", "σ x (cm)", "σ y (cm)"], rows,
                      caption="Radars: residual over the matched reflectors and 1σ of the fitted pose (bundle)"))  # fmt: skip
    if s.filter_counts:
        sec.add(Table(["scene", "A (all)", "B (in range)", "C (removed)"], [[sc, c.get("A", "—"), c.get("B", "—"), c.get("C", "—")] for sc, c in sorted(s.filter_counts.items())],
                      caption="Radar detections through the A/B/C filter, per placement"))  # fmt: skip

    refl = {r: s.reflectors(r) for r in radars}
    have_res = {r: v for r, v in refl.items() if "residual_m" in v}
    labels = {r: [f"{sc} #{i}" for sc, i in zip(v["scene"], v["lidar_index"])] for r, v in have_res.items() if "scene" in v and "lidar_index" in v}
    add("residual per reflector", lambda: rr.reflector_residuals_figure({r: v["residual_m"] for r, v in have_res.items()}, {r: v["used"] for r, v in have_res.items() if "used" in v},
                                                                         {r: v["holdout_m"] for r, v in have_res.items() if "holdout_m" in v}, labels or None),
        {"per-reflector residuals": have_res or None})  # fmt: skip

    # top view: every radar with a pose in the bundle; its detections labelled by what the calibration took them for
    posed = [r for r in radars if entries[r] is not None]
    det_main, cats = {}, {}
    for r in posed:
        xy = np.concatenate([s.radar_xy(sc, r) for sc in scenes]) if scenes else np.zeros((0, 2))
        det_main[r] = rr.radar_points_in_main(xy, entries[r].T)
        cats[r] = [rr.detection_category(lab) for sc in scenes for lab in _labels(s, sc, r)]
    no_pose = [r for r in radars if r not in posed]
    if no_pose:
        skipped_msg = f"{sec.title}: top view without {', '.join(no_pose)} (no T_{main}_<radar> in the bundle)"
        (skipped if skipped is not None else []).append(skipped_msg)
        sec.add(f"top view: {', '.join(no_pose)} not drawn (the bundle has no pose for them).")
    poses = {n[len(f"T_{main}_"):]: e.T for n, e in sorted(transforms.items()) if n.startswith(f"T_{main}_")}
    add("top view", lambda: rr.radar_top_view_figure({sc: s.lidar_centres(sc) for sc in scenes}, det_main, cats, poses, main), {"reflector centres": scenes or None, "radar poses": posed or None})

    have_rcs = [r for r in radars if any(s.rcs(sc, r) is not None for sc in scenes)]
    rng_by, rcs_by, cat_by = {}, {}, {}
    for r in have_rcs:
        parts = [(s.radar_xy(sc, r), s.rcs(sc, r), _labels(s, sc, r)) for sc in scenes if s.rcs(sc, r) is not None]
        rng_by[r] = np.concatenate([np.hypot(*xy.T) if len(xy) else np.zeros(0) for xy, _, _ in parts])
        rcs_by[r] = np.concatenate([c for _, c, _ in parts])
        cat_by[r] = [rr.detection_category(lab) for _, _, labs in parts for lab in labs]
    add("RCS against range", lambda: rr.rcs_range_figure(rng_by, rcs_by, cat_by), {"RCS per detection": have_rcs or None})

    sig = {r: entries[r].sigma for r in posed if entries[r].sigma and "yaw_deg" in entries[r].sigma}
    add("pose uncertainty", lambda: rr.radar_sigma_figure(list(sig), [v["yaw_deg"] for v in sig.values()], [v.get("x_m", np.nan) for v in sig.values()],
                                                          [v.get("y_m", np.nan) for v in sig.values()], [v.get("jackknife_yaw_deg", np.nan) for v in sig.values()]),
        {"σ of the radar poses": sig or None})  # fmt: skip

    lidar_rows = []
    for n, e in sorted(transforms.items()):
        res = e.residual or {}
        if n.startswith(f"T_{main}_") and "fitness" in res:
            sg = e.sigma or {}
            rot, tr = np.asarray(sg.get("rot_deg", [np.nan] * 3), float).ravel(), np.asarray(sg.get("trans_m", [np.nan] * 3), float).ravel()
            lidar_rows.append([n, _f(res.get("initial_fitness"), 1, ".3f"), _f(res.get("fitness"), 1, ".3f"), _f(res.get("initial_rmse_m"), 100, ".1f"), _f(res.get("inlier_rmse_m"), 100, ".1f"),
                               " / ".join(_f(v, 1, ".3f") for v in rot), " / ".join(_f(v, 100, ".2f") for v in tr)])  # fmt: skip
    if lidar_rows:
        sec.add(Table(["transform", "fitness before", "after", "inlier RMSE before (cm)", "after (cm)", "σ rot x/y/z (deg)", "σ trans x/y/z (cm)"], lidar_rows,
                      caption="LiDAR-LiDAR registrations (bundle)"))  # fmt: skip
    return sec


def _labels(s: RadarLidarSession, scene: str, radar: str) -> list[str]:
    """What each detection of ``radar`` in ``scene`` was taken for (``detection`` when the session did not say)."""
    n = len(s.radar_xy(scene, radar))
    lab = [str(x) for x in ((s.detections or {}).get(scene) or {}).get(radar, [])]
    return lab if len(lab) == n else ["detection"] * n if not lab else (lab + ["ghost"] * n)[:n]

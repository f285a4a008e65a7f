"""``radarcal radar-lidar`` as one call: ``calibrate(session, options) -> RadarLidarResult``, the typed session file
(:class:`RadarLidarSession`) and what is stored in the bundle (:meth:`RadarLidarResult.store`).

Checks that refuse a result (nothing stored without ``force``): a LiDAR pose whose worst-observed direction has
3 sigma beyond ``lidar_tolerance`` (the direction is named), whose overlap fitness fell, or that moved farther than
``max_move`` from its (ground-pre-aligned) guess; a radar pose farther than ``max_move`` from its ``initial_T_main``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError
from radarcal.extrinsics.radar.detections import frames_per_source
from radarcal.extrinsics.radar.geometry2d import multipath_of
from radarcal.extrinsics.radar.reflectors import (
    board_reflector_centres,
    extract_reflectors,
)
from radarcal.extrinsics.radar_lidar_session import RadarLidarSession  # the typed session file (no solver import)
from radarcal.extrinsics.radar.rig import (
    RigCalibration,
    SceneObs,
    build_scene_obs,
    calibrate_rig,
)

__all__ = ["RadarLidarOptions", "RadarLidarResult", "RadarLidarSession", "calibrate"]


@dataclass
class RadarLidarOptions:
    model: str = "slant"  # slant | planar
    gate: float = 0.35  # radar <-> reflector matching gate (m)
    outlier: float = 0.15  # hold-out residual (m) above which a reflector may be rejected
    joint: bool = True
    lidar_method: str = "gicp"  # gicp | point_to_plane
    voxel: float = 0.1
    max_move_deg: float = 15.0  # a pose farther than this from its guess is refused
    max_move_m: float = 1.0
    lidar_tolerance_deg: float = 0.2  # a LiDAR pose is stored only when 3 sigma of its worst direction is within these
    lidar_tolerance_m: float = 0.02


@dataclass
class RadarLidarResult:
    rig: object  # radarcal.io.radar.RigConfig
    cal: RigCalibration | None
    lidars: dict  # name -> {"registration": LidarRegistration, "refinement": LidarRefinement, "T": 4x4, "refused": str | None}
    scenes: list  # [SceneObs]
    frames: dict
    notes: list
    refusals: list  # ["<sensor>: <why>"]
    detection_labels: dict  # scene -> radar -> [label]
    options: RadarLidarOptions
    extraction: dict  # scene -> {"methods": [...], "rejected": [...]}

    @property
    def refused(self) -> bool:
        return bool(self.refusals)

    def session_file(self) -> RadarLidarSession:
        cal = self.cal
        rs = cal.radars if cal else {}
        return RadarLidarSession.build(cal.T_lidar_G if cal else np.eye(4), {s.name: s.lidar_centres for s in self.scenes}, {s.name: dict(s.radar_xy) for s in self.scenes},
                                       {s.name: dict(s.radar_rcs or {}) for s in self.scenes}, {r: v.per_reflector for r, v in rs.items()},
                                       model=self.options.model, main_lidar=self.rig.main_lidar, reference_radar=self.rig.reference_radar,
                                       filter_counts=cal.filter_counts if cal else {}, quantisation=dict(cal.quantisation) if cal else {}, notes=list(self.notes),
                                       joint=cal.joint if cal else {}, detections=self.detection_labels)

    def store(self, bundle_path: Path, command: str, input_files: list) -> None:
        """Write every transform, the sensors and the session file into the bundle (created if missing)."""
        from radarcal.bundle import (
            Provenance,
            hash_inputs,
            load_or_create_bundle,
            save_bundle,
        )

        o = self.options
        b = load_or_create_bundle(bundle_path)
        prov = Provenance(command=command, inputs_sha256=hash_inputs(input_files, {"model": o.model, "gate": o.gate, "outlier": o.outlier, "joint": o.joint}))
        main = self.rig.main_lidar
        b.set_sensor(main, type="lidar", main=True)
        for r, d in self.summary()["radars"].items():
            res = self.cal.radars[r]
            b.set_sensor(r, type="radar", mount_height_m=float(res.mount_height), mount_height_estimated=self.rig.mount_heights.get(r) is None)
            b.set_transform(main, r, res.T_lidar_radar, method=f"radar-lidar: corner reflectors, {o.model} model, RCS-weighted NLS{' + joint refinement' if o.joint else ''}",
                            residual=d["residual"], sigma=d["sigma"], provenance=prov)
        for n, d in self.summary()["lidars"].items():
            b.set_sensor(n, type="lidar")
            b.set_transform(main, n, self.lidars[n]["T"], method=d["method"], residual={k: d[k] for k in ("fitness", "inlier_rmse_m", "initial_fitness", "initial_rmse_m", "eval_distance_m")},
                            sigma={"rot_deg": d["sigma_rot_deg"], "trans_m": d["sigma_trans_m"]}, provenance=prov)
        if self.rig.T_vehicle_main is not None:
            b.set_sensor("vehicle", type="frame")
            b.set_transform("vehicle", main, self.rig.T_vehicle_main, method="given in rig.yaml (T_vehicle_main)", provenance=prov)
        if self.cal is not None:
            if b.path is None:
                b.path = Path(bundle_path)
            self.session_file().save(b, "radar_lidar")
        save_bundle(b, bundle_path)

    def summary(self) -> dict:
        """Everything printed (and ``--json``): per scene, radar and LiDAR."""
        cal, rig, o = self.cal, self.rig, self.options
        radars = {}
        for r, res in (cal.radars.items() if cal else []):
            f = res.fit
            used = [p for p in res.per_reflector if p["used"]]
            resid = {"rms_m": f.rms, "n": len(used), "max_m": max((p["residual_m"] for p in used), default=float("nan")),
                     "holdout_rms_m": res.loo.get("holdout_rms", float("nan")), "rejected": len(res.rejected), "model": f.model}
            sig = {"yaw_deg": float(np.degrees(res.sigma_G["theta"])), "x_m": res.sigma_G["a"], "y_m": res.sigma_G["b"]}
            if "height" in res.sigma_G:
                sig["mount_height_m"] = res.sigma_G["height"]
            jk = res.loo.get("jackknife_sigma") or {}
            if jk:
                sig["jackknife_yaw_deg"] = float(np.degrees(jk["theta"]))
            xyz = geometry.T_to_xyz_rpy_deg(res.T_lidar_radar)
            pp = res.pairwise_pose_ref
            radars[r] = {"T_main_radar": res.T_lidar_radar, "xyz_m": xyz[:3], "rpy_deg": xyz[3:],
                         "ground_pose": {"yaw_deg": float(np.degrees(res.pose_G.theta)), "a_m": res.pose_G.t[0], "b_m": res.pose_G.t[1]},
                         "patent_chain_ground_pose": None if res.patent_pose_G is None else {"yaw_deg": float(np.degrees(res.patent_pose_G.theta)), "a_m": res.patent_pose_G.t[0],
                                                                                            "b_m": res.patent_pose_G.t[1]},
                         "mount_height_m": res.mount_height, "residual": resid, "sigma": sig,
                         "rejected": [{"scene": i[0], "lidar_index": i[1], "why": w} for i, w in res.rejected], "per_reflector": list(res.per_reflector),
                         "radar_radar": None if pp is None else {"reference": rig.reference_radar, "theta1_deg": float(np.degrees(pp.theta)), "a1_m": pp.t[0], "b1_m": pp.t[1],
                                                                 "rms_m": cal.radar_radar.get(r, {}).get("rms")}}
        lidars = {}
        for n, d in self.lidars.items():
            reg, ref = d["registration"], d["refinement"]
            lidars[n] = {"T_main_lidar": d["T"], "method": d["method"], "fitness": reg.fitness, "inlier_rmse_m": reg.inlier_rmse, "initial_fitness": reg.initial_fitness,
                         "initial_rmse_m": reg.initial_rmse, "eval_distance_m": reg.eval_distance, "correction_deg": reg.correction_deg, "correction_m": reg.correction_m,
                         "reflector_pairs": ref.n_reflectors, "reflector_rms_m": ref.reflector_rms_m, "sigma_rot_deg": ref.sigma_rot_deg, "sigma_trans_m": ref.sigma_trans_m,
                         "worst_translation": {"sigma_m": ref.worst_trans[0], "direction": ref.worst_trans[1]},
                         "worst_rotation": {"sigma_deg": ref.worst_rot[0], "axis": ref.worst_rot[1]}, "refused": d["refused"]}
        g = cal.T_lidar_G if cal else np.eye(4)
        return {"main_lidar": rig.main_lidar, "model": o.model, "scenes": len(self.scenes), "reflectors_per_scene": {s.name: len(s.lidar_centres) for s in self.scenes},
                "radar_frames": self.frames, "filter_counts": cal.filter_counts if cal else {}, "radars": radars, "lidars": lidars, "joint": cal.joint if cal else {},
                "quantisation": dict(cal.quantisation) if cal else {}, "notes": self.notes, "refusals": self.refusals, "detections": self.detection_labels,
                "extraction": self.extraction, "ground": {"normal": g[:3, 2], "lidar_height_m": float(-(g[:3, 2] @ g[:3, 3]))}}


def _label_detections(cal: RigCalibration, scenes: list, radar_names: list, gate: float) -> dict:
    """Per scene and radar, what each (frame-averaged) detection was taken for: ``reflector <i>`` (matched, used),
    ``rejected (reflector <i>)``, ``multipath ghost of reflector <i>`` (where LiDAR reflector i's ground-bounce ghost
    falls under the calibrated pose, :func:`multipath_of` -- its bearing, its ground-mirror image's slant range -- and
    weaker than its matched detection), ``clutter (low RCS)`` (10 dB below the matched ones), ``ghost`` (nothing else)."""
    T_G_lidar = geometry.invert_T(cal.T_lidar_G)
    out = {}
    for sc in scenes:
        per = {}
        p_G = geometry.transform_points(T_G_lidar, np.asarray(sc.lidar_centres, float).reshape(-1, 3))
        for r in radar_names:
            m = np.asarray(sc.radar_xy.get(r, np.zeros((0, 2))), float).reshape(-1, 2)
            rc = (sc.radar_rcs or {}).get(r)
            lab = ["ghost"] * len(m)
            res = cal.radars.get(r)
            if res is None:
                per[r] = lab
                continue
            matched = {}  # radar index -> LiDAR index
            for p in res.per_reflector:
                if p["scene"] == sc.name:
                    matched[p["radar_index"]] = p["lidar_index"]
                    lab[p["radar_index"]] = f"reflector {p['lidar_index']}" if p["used"] else f"rejected (reflector {p['lidar_index']})"
            rcs_of = {li: rc[j] for j, li in matched.items()} if rc is not None else {}
            ref_rcs = np.nanpercentile(rc[list(matched)], 50) if rc is not None and matched and np.isfinite(rc[list(matched)]).any() else None
            rest = np.array([j for j in range(len(m)) if j not in matched], int)
            on = multipath_of(m[rest], res.pose_G.inverse().apply(p_G[:, :2]), p_G[:, 2], res.mount_height, gate, ghost_only=True) if len(rest) else np.zeros(0, int)
            for j, k in zip(rest, on):  # unmatched detections (few)
                if k >= 0 and (rc is None or k not in rcs_of or rc[j] < rcs_of[k]):
                    lab[j] = f"multipath ghost of reflector {k}"
                elif ref_rcs is not None and rc[j] < ref_rcs - 10:
                    lab[j] = "clutter (low RCS)"
            per[r] = lab
        out[sc.name] = per
    return out


def calibrate(inp, options: RadarLidarOptions | None = None, progress=lambda it, what: it, log=lambda msg: None) -> RadarLidarResult:
    """Every radar and LiDAR of ``inp`` (:class:`radarcal.io.radar.RadarSessionInput`) into the main LiDAR frame.
    Raises :class:`InputError` for sessions that cannot be calibrated (no reflector seen, a radar with fewer than two
    usable detections, a missing cloud); refusals of the checks are in ``result.refusals``."""
    o = options or RadarLidarOptions()
    rig = inp.rig
    scenes, notes, frames, extraction = [], [], {}, {}
    lidar_clouds: dict[str, list] = {n: [] for n in rig.lidars}
    main_centres = []
    frames_each = {r: frames_per_source([sc.detections.of(r) for sc in inp.scenes]) for r in rig.radars}
    for sc in progress(inp.scenes, "reflectors"):
        clouds = {lid: sc.cloud(lid) for lid in sc.clouds}
        for lid, c in clouds.items():
            lidar_clouds[lid].append(c.points.astype(float))
        det = sc.detections
        xy = {r: det.of(r) for r in rig.radars}
        rcs = {r: det.rcs[det.radar == r] for r in rig.radars}
        if rig.main_lidar in sc.centres or rig.main_lidar in sc.boards:
            if rig.main_lidar in sc.boards:  # TU Delft boards: reflector behind the mean of each board's circle centres
                circles, board_offset = sc.boards[rig.main_lidar]
                c = board_reflector_centres(circles, board_offset)
            else:  # reflector centres given: detections as they are
                c = np.asarray(sc.centres[rig.main_lidar], float).reshape(-1, 3)
            obs = SceneObs(sc.name, c, dict(xy), None, xy, rcs)
            counts = {r: np.ones(len(v), int) for r, v in xy.items()}
            extraction[sc.name] = {"methods": ["given"] * len(c), "rejected": []}
        else:
            main = clouds[rig.main_lidar]
            if not rig.radars:
                obs, counts = SceneObs(sc.name, np.zeros((0, 3)), {}, None), {}
                try:
                    ext = extract_reflectors(main.points.astype(float), range_gate=rig.range_gate, ground_tol=rig.ground_tol, cluster_tol=rig.cluster_tol,
                                             head_size=rig.head_size, offset=rig.reflector_offset, edge=rig.reflector_edge, intensity=main.intensity)
                    obs.lidar_centres = ext.centres
                except ValueError:
                    pass
            else:
                try:
                    obs, ext, counts = build_scene_obs(sc.name, main.points.astype(float), xy, range_gate=rig.range_gate, ground_tol=rig.ground_tol,
                                                       cluster_tol=rig.cluster_tol, head_size=rig.head_size, offset=rig.reflector_offset, radar_rcs=rcs,
                                                       edge=rig.reflector_edge, intensity=main.intensity, frames=frames_each)
                except ValueError as e:
                    raise InputError(sc.clouds[rig.main_lidar], f"reflector extraction failed: {e}") from None
                if len(ext.centres) == 0:
                    why = "; ".join(sorted({w for _, w in ext.rejected})[:3])
                    raise InputError(sc.clouds[rig.main_lidar], f"no reflector seen within {rig.range_gate:g} m of the LiDAR" + (f" (rejected: {why})" if why else ""))
                extraction[sc.name] = {"methods": list(ext.method), "rejected": [{"centre": c, "why": w} for c, w in ext.rejected]}
        scenes.append(obs)
        frames[sc.name] = {r: int(c.max()) if len(c) else 0 for r, c in counts.items()}
        main_centres.append(obs.lidar_centres)
        notes += [f"scene {sc.name}: {n}" for n in sc.notes]
    for r in rig.radars:  # a radar that cannot be calibrated is bad input, not a silent skip
        n = sum(len(s.radar_xy.get(r, ())) for s in scenes)
        if n < 2:
            raise InputError(Path(rig.path).parent / "scenes" if inp.kind == "session" else inp.root,
                             f"radar {r!r}: {n} detection{'s' if n != 1 else ''} in all scenes (needs at least 2 reflectors)")
    cal = None
    refusals = []
    if rig.radars:
        try:
            cal = calibrate_rig(scenes, rig.radars, rig.mount_heights, reference=rig.reference_radar, init_T_lidar_radar={r: rig.init_T_main.get(r) for r in rig.radars},
                                model=o.model, gate=o.gate, forward=rig.forward, lateral=rig.lateral, outlier_threshold=o.outlier, joint=o.joint,
                                lidar_range_gate=rig.range_gate if inp.kind == "session" else None)
        except ValueError as e:
            raise InputError(inp.root, str(e)) from None
        notes += cal.notes
        missing = [r for r in rig.radars if r not in cal.radars]
        if missing:
            raise InputError(inp.root, f"radar(s) {', '.join(missing)}: fewer than 2 detections matched to LiDAR reflectors")
        for r, res in cal.radars.items():
            T0 = rig.init_T_main.get(r)
            if T0 is not None:
                deg, m = geometry.pose_error(res.T_lidar_radar, T0)
                if deg > o.max_move_deg or m > o.max_move_m:
                    refusals.append(f"{r}: moved {deg:.1f} deg / {m:.2f} m from its initial_T_main (limit {o.max_move_deg:g} deg / {o.max_move_m:g} m): implausible")
    lidars = _register_lidars(inp, o, lidar_clouds, main_centres, refusals, log)
    labels = _label_detections(cal, scenes, rig.radars, o.gate) if cal is not None else {}
    return RadarLidarResult(rig, cal, lidars, scenes, frames, notes, refusals, labels, o, extraction)


def _register_lidars(inp, o: RadarLidarOptions, lidar_clouds: dict, main_centres: list, refusals: list, log) -> dict:
    """Every other LiDAR to the main one: GICP, then the reflector-constrained refinement; the checks append to
    ``refusals``. Returns name -> {registration, refinement, T, refused, method}."""
    rig = inp.rig
    lidars = {}
    others = [n for n in rig.lidars if n != rig.main_lidar and lidar_clouds[n]]
    if others:
        from radarcal.extrinsics.radar.lidar_lidar import (
            axis_name,
            refine_with_reflectors,
            register_lidar,
        )

        target = np.concatenate(lidar_clouds[rig.main_lidar])
        for n in others:
            if n not in rig.init_T_main:
                raise InputError(Path(rig.path), f"lidars.{n}.initial_T_main: an initial guess is needed for LiDAR-LiDAR registration")
            if len(lidar_clouds[n]) != len(lidar_clouds[rig.main_lidar]):
                raise InputError(inp.root, f"{n}: clouds in {len(lidar_clouds[n])} of {len(lidar_clouds[rig.main_lidar])} scenes")
            log(f"registering {n} -> {rig.main_lidar} ({o.lidar_method})")
            src = np.concatenate(lidar_clouds[n])
            try:
                reg = register_lidar(src, target, rig.init_T_main[n], method=o.lidar_method, voxel=o.voxel)
            except ValueError as e:
                raise InputError(inp.root, f"{n}: registration failed: {e}") from None
            src_refl = []
            for c in lidar_clouds[n]:  # per scene
                try:
                    src_refl.append(extract_reflectors(c, range_gate=rig.range_gate + 2.5, ground_tol=rig.ground_tol, cluster_tol=rig.cluster_tol, head_size=rig.head_size,
                                                       offset=rig.reflector_offset, edge=rig.reflector_edge).centres)
                except ValueError:
                    src_refl.append(np.zeros((0, 3)))
            ref = refine_with_reflectors(src, target, reg.T_target_source, src_refl, main_centres)
            T = ref.T_target_source if ref.n_reflectors >= 2 else reg.T_target_source
            method = f"lidar-lidar: open3d {reg.method} from the initial guess (ground pre-alignment)" + (f" + {ref.n_reflectors} reflector point constraints" if ref.n_reflectors >= 2 else "")
            why = None
            s_t, d_t = ref.worst_trans
            s_r, d_r = ref.worst_rot
            if 3 * s_t > o.lidar_tolerance_m:
                why = f"{n}: translation along {axis_name(d_t, rig.main_lidar)} is not observed (3 sigma {300 * s_t:.1f} cm > {100 * o.lidar_tolerance_m:g} cm: add reflectors both LiDARs see, or structure across it)"
            elif 3 * s_r > o.lidar_tolerance_deg:
                why = f"{n}: rotation about {axis_name(d_r, rig.main_lidar)} is not observed (3 sigma {3 * s_r:.2f} deg > {o.lidar_tolerance_deg:g} deg: add reflectors both LiDARs see, or structure across it)"
            elif reg.fitness < reg.initial_fitness:
                why = f"{n}: overlap fitness fell from {reg.initial_fitness:.3f} to {reg.fitness:.3f}"
            else:
                deg, m = geometry.pose_error(T, reg.T_start)  # from the guess after the ground fixed its tilt and height
                if deg > o.max_move_deg or m > o.max_move_m:
                    why = f"{n}: moved {deg:.1f} deg / {m:.2f} m from its guess (limit {o.max_move_deg:g} deg / {o.max_move_m:g} m): implausible"
            if why:
                refusals.append(why)
            lidars[n] = {"registration": reg, "refinement": ref, "T": T, "refused": why, "method": method}
    return lidars

"""``radarcal radar-lidar SESSION --bundle B``: every radar and LiDAR of a rig into the main LiDAR frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from radarcal import geometry
from radarcal.bundle import Provenance, hash_inputs, load_or_create_bundle, save_bundle, save_session
from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console, progress
from radarcal.errors import InputError


def radar_lidar(
    session: Path = typer.Argument(..., help="Session folder: rig.yaml + scenes/<k>/{<lidar>.pcd, radar.csv}."),
    bundle: Path = BundleOpt,
    model: str = typer.Option("slant", "--model", help="slant (mounting heights + ground plane, default) or planar (the patent's: z dropped)."),
    gate: float = typer.Option(0.35, "--gate", help="Matching gate (m) between radar detections and reflectors."),
    outlier: float = typer.Option(0.15, "--outlier", help="Reject a reflector whose hold-out residual exceeds this (m) and 4x the others' scale."),
    joint: bool = typer.Option(True, "--joint/--no-joint", help="Joint refinement of all radars at once."),
    lidar_method: str = typer.Option("gicp", "--lidar-method", help="LiDAR-LiDAR registration: gicp or point_to_plane."),
    voxel: float = typer.Option(0.1, "--voxel", help="Finest voxel size (m) of the LiDAR-LiDAR registration."),
    as_json: bool = JsonOpt,
) -> None:
    """Radar <-> radar, LiDAR <-> radar (corner reflectors) and LiDAR <-> LiDAR (GICP) into one bundle."""
    from radarcal.extrinsics.radar_lidar import build_scene_obs, calibrate_rig
    from radarcal.io import read_cloud
    from radarcal.io.radar import read_radar_session

    if model not in ("slant", "planar"):
        raise InputError("--model", f"expected slant or planar, got {model!r}")
    if lidar_method not in ("gicp", "point_to_plane"):
        raise InputError("--lidar-method", f"expected gicp or point_to_plane, got {lidar_method!r}")
    inp = read_radar_session(session)
    rig = inp.rig
    scenes, extractions, notes, frames = [], {}, [], {}
    clouds: dict[str, list] = {n: [] for n in rig.lidars}
    for sc in progress(inp.scenes, "reflectors"):
        pts = {}
        for lid, path in sc.clouds.items():
            c = read_cloud(path)
            if len(c) == 0:
                raise InputError(path, "empty point cloud")
            pts[lid] = c.points.astype(float)
            clouds[lid].append(pts[lid])
        try:
            obs, ext, counts = build_scene_obs(sc.name, pts[rig.main_lidar], {r: sc.detections.of(r) for r in rig.radars}, range_gate=rig.range_gate,
                                               ground_tol=rig.ground_tol, cluster_tol=rig.cluster_tol, head_size=rig.head_size, offset=rig.reflector_offset)
        except ValueError as e:
            raise InputError(sc.clouds[rig.main_lidar], f"reflector extraction failed: {e}") from None
        if len(ext.centres) == 0:
            raise InputError(sc.clouds[rig.main_lidar], f"no reflector cluster within {rig.range_gate:g} m of the LiDAR")
        scenes.append(obs)
        extractions[sc.name] = ext
        frames[sc.name] = {r: int(c.max()) if len(c) else 0 for r, c in counts.items()}
        notes += [f"scene {sc.name}: {n}" for n in sc.notes]
    try:
        cal = calibrate_rig(scenes, rig.radars, rig.mount_heights, reference=rig.reference_radar, init_T_lidar_radar={r: rig.init_T_main.get(r) for r in rig.radars},
                            model=model, gate=gate, forward=rig.forward, lateral=rig.lateral, outlier_threshold=outlier, joint=joint)
    except ValueError as e:
        raise InputError(session, str(e)) from None
    notes += cal.notes
    # LiDAR <-> LiDAR
    lidar_regs = {}
    others = [n for n in rig.lidars if n != rig.main_lidar and clouds[n]]
    if others:
        from radarcal.extrinsics.lidar_lidar import register_lidar

        target = np.concatenate(clouds[rig.main_lidar])
        for n in others:
            if n not in rig.init_T_main:
                raise InputError(Path(rig.path), f"lidars.{n}.initial_T_main: an initial guess is needed for LiDAR-LiDAR registration")
            err_console.print(f"registering {n} -> {rig.main_lidar} ({lidar_method})", style="dim")
            try:
                lidar_regs[n] = register_lidar(np.concatenate(clouds[n]), target, rig.init_T_main[n], method=lidar_method, voxel=voxel)
            except ValueError as e:
                raise InputError(session, f"{n}: registration failed: {e}") from None

    # --- bundle -------------------------------------------------------------------------------------------------
    b = load_or_create_bundle(bundle)
    prov = Provenance(command=command_line(), inputs_sha256=hash_inputs(inp.input_files(), {"model": model, "gate": gate, "outlier": outlier, "joint": joint}))
    main = rig.main_lidar
    b.set_sensor(main, type="lidar", main=True)
    summary_radars = {}
    for r, res in cal.radars.items():
        f = res.fit
        used = [p for p in res.per_reflector if p["used"]]
        resid = {"rms_m": f.rms, "n": len(used), "max_m": max((p["residual_m"] for p in used), default=float("nan")), "holdout_rms_m": res.loo.get("holdout_rms", float("nan")),
                 "rejected": len(res.rejected), "model": f.model}
        sig = {"yaw_deg": float(np.degrees(res.sigma_G["theta"])), "x_m": res.sigma_G["a"], "y_m": res.sigma_G["b"]}
        if "height" in res.sigma_G:
            sig["mount_height_m"] = res.sigma_G["height"]
        jk = res.loo.get("jackknife_sigma") or {}
        if jk:
            sig["jackknife_yaw_deg"] = float(np.degrees(jk["theta"]))
        b.set_sensor(r, type="radar", mount_height_m=float(res.mount_height), mount_height_estimated=rig.mount_heights.get(r) is None)
        b.set_transform(main, r, res.T_lidar_radar, method=f"radar-lidar: corner reflectors, {model} model, NLS{' + joint refinement' if joint else ''}", residual=resid, sigma=sig, provenance=prov)
        xyz = geometry.T_to_xyz_rpy_deg(res.T_lidar_radar)
        summary_radars[r] = {"T_main_radar": res.T_lidar_radar, "xyz_m": xyz[:3], "rpy_deg": xyz[3:], "ground_pose": {"yaw_deg": float(np.degrees(res.pose_G.theta)), "a_m": res.pose_G.t[0], "b_m": res.pose_G.t[1]},
                             "patent_chain_ground_pose": None if res.patent_pose_G is None else {"yaw_deg": float(np.degrees(res.patent_pose_G.theta)), "a_m": res.patent_pose_G.t[0], "b_m": res.patent_pose_G.t[1]},
                             "mount_height_m": res.mount_height, "residual": resid, "sigma": sig, "rejected": [{"scene": i[0], "lidar_index": i[1], "why": w} for i, w in res.rejected],
                             "per_reflector": [{k: v for k, v in p.items()} for p in res.per_reflector],
                             "radar_radar": None if res.pairwise_pose_ref is None else {"reference": rig.reference_radar, "theta1_deg": float(np.degrees(res.pairwise_pose_ref.theta)), "a1_m": res.pairwise_pose_ref.t[0], "b1_m": res.pairwise_pose_ref.t[1],
                                                                                       "rms_m": cal.radar_radar.get(r, {}).get("rms")}}
    summary_lidars = {}
    for n, reg in lidar_regs.items():
        b.set_sensor(n, type="lidar")
        b.set_transform(main, n, reg.T_target_source, method=f"lidar-lidar: open3d {reg.method} from the rig.yaml initial guess (ground pre-alignment)",
                        residual={"fitness": reg.fitness, "inlier_rmse_m": reg.inlier_rmse, "initial_fitness": reg.initial_fitness, "initial_rmse_m": reg.initial_rmse, "eval_distance_m": reg.eval_distance},
                        provenance=prov)
        summary_lidars[n] = {"T_main_lidar": reg.T_target_source, "fitness": reg.fitness, "inlier_rmse_m": reg.inlier_rmse, "initial_fitness": reg.initial_fitness, "initial_rmse_m": reg.initial_rmse,
                             "eval_distance_m": reg.eval_distance, "correction_deg": reg.correction_deg, "correction_m": reg.correction_m}
    if rig.T_vehicle_main is not None:
        b.set_sensor("vehicle", type="frame")
        b.set_transform("vehicle", main, rig.T_vehicle_main, method="given in rig.yaml (T_vehicle_main)", provenance=prov)
    arrays = {"T_lidar_G": cal.T_lidar_G}
    for s in scenes:
        arrays[f"scene/{s.name}/lidar_centres"] = s.lidar_centres
        for r, xy in s.radar_xy.items():
            arrays[f"scene/{s.name}/radar/{r}"] = xy
    for r, res in cal.radars.items():
        arrays[f"radar/{r}/residual_m"] = np.array([p["residual_m"] for p in res.per_reflector])
        arrays[f"radar/{r}/holdout_m"] = np.array([p["holdout_residual_m"] for p in res.per_reflector])
        arrays[f"radar/{r}/radar_xy"] = np.array([p["radar_xy"] for p in res.per_reflector]).reshape(-1, 2)
        arrays[f"radar/{r}/used"] = np.array([p["used"] for p in res.per_reflector], bool)
    meta = {"model": model, "main_lidar": main, "reference_radar": rig.reference_radar, "filter_counts": cal.filter_counts, "quantisation": cal.quantisation, "notes": notes, "joint": cal.joint}
    save_session(b, "radar_lidar", arrays, meta)
    save_bundle(b, bundle)

    summary = {"bundle": str(bundle), "session": str(session), "main_lidar": main, "model": model, "scenes": len(scenes),
               "reflectors_per_scene": {s.name: int(len(s.lidar_centres)) for s in scenes}, "radar_frames": frames, "filter_counts": cal.filter_counts,
               "radars": summary_radars, "lidars": summary_lidars, "joint": cal.joint, "quantisation": {k: v for k, v in cal.quantisation.items()}, "notes": notes,
               "ground": {"normal": cal.T_lidar_G[:3, 2], "lidar_height_m": float(cal.T_lidar_G[:3, 2] @ cal.T_lidar_G[:3, 3] * -1)}}
    emit(summary, as_json, _human)


def _human(s: dict) -> None:
    typer.echo(f"radar-lidar: {s['scenes']} placement(s), main LiDAR {s['main_lidar']}, model {s['model']} (LiDAR {s['ground']['lidar_height_m']:.3f} m above the fitted ground)")
    for name, c in s["filter_counts"].items():
        typer.echo(f"  scene {name}: {s['reflectors_per_scene'][name]} LiDAR reflector(s); radar detections A={c['A']} B={c['B']} C={c['C']}")
    for r, d in s["radars"].items():
        x, y, z = d["xyz_m"]
        rr, pp, yy = d["rpy_deg"]
        sg = d["sigma"]
        typer.echo(f"  T_{s['main_lidar']}_{r}: xyz=({x:.4f}, {y:.4f}, {z:.4f}) m rpy=({rr:.3f}, {pp:.3f}, {yy:.3f}) deg  mount {d['mount_height_m']:.3f} m")
        typer.echo(f"      residual {d['residual']['rms_m'] * 100:.2f} cm RMS over {d['residual']['n']} (hold-out {d['residual']['holdout_rms_m'] * 100:.2f} cm), "
                   f"sigma yaw {sg['yaw_deg']:.3f} deg, x {sg['x_m'] * 100:.2f} cm, y {sg['y_m'] * 100:.2f} cm")
        if d["radar_radar"]:
            q = d["radar_radar"]
            typer.echo(f"      -> {q['reference']}: theta1 {q['theta1_deg']:.3f} deg, (a1, b1) = ({q['a1_m']:.3f}, {q['b1_m']:.3f}) m, rms {100 * (q['rms_m'] or 0):.2f} cm")
        for rej in d["rejected"]:
            typer.echo(f"      rejected scene {rej['scene']} reflector {rej['lidar_index']}: {rej['why']}")
    for n, d in s["lidars"].items():
        typer.echo(f"  T_{s['main_lidar']}_{n}: fitness {d['initial_fitness']:.3f} -> {d['fitness']:.3f}, inlier RMSE {d['initial_rmse_m']:.3f} -> {d['inlier_rmse_m']:.3f} m "
                   f"(at {d['eval_distance_m']:g} m; moved {d['correction_deg']:.2f} deg / {d['correction_m']:.3f} m from the guess)")
    if s["quantisation"].get("quantised"):
        typer.echo(f"  note: {s['quantisation']['note']}")
    for n in s["notes"]:
        typer.echo(f"  note: {n}")
    typer.echo(f"  -> {s['bundle']}")

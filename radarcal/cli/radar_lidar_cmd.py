"""``radarcal radar-lidar SESSION --bundle B``: every radar and LiDAR of a rig into the main LiDAR frame."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer

from radarcal.cli.common import (
    BundleOpt,
    CloudTopicOpt,
    JsonOpt,
    command_line,
    emit,
    err_console,
    progress,
)
from radarcal.errors import InputError


class Model(str, Enum):
    slant = "slant"
    planar = "planar"


class LidarMethod(str, Enum):
    gicp = "gicp"
    point_to_plane = "point_to_plane"


def radar_lidar(
    session: Path = typer.Argument(..., help="Session folder (rig.yaml + scenes/), the TU Delft example folder or OpenCalib's lidar2lidar sample."),
    bundle: BundleOpt = ...,
    model: Model = typer.Option(Model.slant, "--model", help="slant (mounting heights + ground plane) or planar (the patent's: z dropped)."),
    gate: float = typer.Option(0.35, "--gate", help="Matching gate (m) between radar detections and reflectors."),
    outlier: float = typer.Option(0.15, "--outlier", help="Reject a reflector whose hold-out residual exceeds this (m) and 3 sigma of the others' fit (leverage removed)."),
    joint: bool = typer.Option(True, "--joint/--no-joint", help="Joint refinement of all radars at once."),
    lidar_method: LidarMethod = typer.Option(LidarMethod.gicp, "--lidar-method", help="LiDAR-LiDAR registration."),
    voxel: float = typer.Option(0.1, "--voxel", help="Finest voxel size (m) of the LiDAR-LiDAR registration."),
    lidar_tol: str = typer.Option("0.2,0.02", "--lidar-tolerance", help="DEG,M: a LiDAR pose is stored only when 3 sigma of its worst rotation / translation is within these."),
    force: bool = typer.Option(False, "--force", help="Store even what the checks refuse (unobserved LiDAR direction, implausible move)."),
    cloud_topic: CloudTopicOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Radar <-> radar, LiDAR <-> radar (corner reflectors) and LiDAR <-> LiDAR (GICP + reflectors) into one bundle."""
    from radarcal.extrinsics.radar.session import RadarLidarOptions, calibrate
    from radarcal.io.radar import read_radar_session

    try:
        tol_deg, tol_m = (float(v) for v in lidar_tol.split(","))
    except ValueError:
        raise InputError("--lidar-tolerance", f"expected DEG,M (two numbers), got {lidar_tol!r}") from None
    inp = read_radar_session(session, cloud_topic)
    opts = RadarLidarOptions(model=model.value, gate=gate, outlier=outlier, joint=joint, lidar_method=lidar_method.value, voxel=voxel,
                             lidar_tolerance_deg=tol_deg, lidar_tolerance_m=tol_m)
    res = calibrate(inp, opts, progress=progress, log=lambda m: err_console.print(m, style="dim"))
    stored = force or not res.refused
    if stored:
        res.store(bundle, command_line(), inp.input_files())
    summary = {"bundle": str(bundle), "session": str(session), "stored": stored, **res.summary()}
    emit(summary, as_json, _human)
    if not stored:
        raise typer.Exit(1)


def _human(s: dict) -> None:
    ground = f", model {s['model']} (LiDAR {s['ground']['lidar_height_m']:.3f} m above the fitted ground)" if s["radars"] else ""
    typer.echo(f"radar-lidar: {s['scenes']} placement(s), main LiDAR {s['main_lidar']}{ground}")
    for name, c in s["filter_counts"].items():
        typer.echo(f"  scene {name}: {s['reflectors_per_scene'][name]} LiDAR reflector(s); radar detections A={c['A']} B={c['B']} C={c['C']}")
        for r, labels in s["detections"].get(name, {}).items():
            odd = sorted({x for x in labels if not x.startswith("reflector")})
            if odd:
                typer.echo(f"      {r}: " + ", ".join(f"{labels.count(x)} {x}" for x in odd))
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
                   f"(at {d['eval_distance_m']:g} m; moved {d['correction_deg']:.2f} deg / {d['correction_m']:.3f} m from the guess); {d['reflector_pairs']} reflector pair(s), "
                   f"worst sigma {d['worst_translation']['sigma_m'] * 100:.2f} cm / {d['worst_rotation']['sigma_deg']:.3f} deg")
    if s["quantisation"].get("quantised"):
        typer.echo(f"  note: {s['quantisation']['note']}")
    for n in s["notes"]:
        typer.echo(f"  note: {n}")
    for n in s["refusals"]:
        typer.echo(f"  refused: {n}")
    typer.echo(f"  -> {s['bundle']}" if s["stored"] else "  NOT stored (refused by the checks above; --force to store anyway)")

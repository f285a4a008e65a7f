"""``radarcal lidar-camera``: LiDAR -> camera extrinsics from manual picks / boards, refined by edge alignment
(the work is :func:`radarcal.extrinsics.lidar_camera_calibrate.calibrate`)."""

from __future__ import annotations

import time
from enum import Enum
from pathlib import Path

import numpy as np
import typer

from radarcal.cli.common import BundleOpt, CloudTopicOpt, JsonOpt, command_line, emit, err_console
from radarcal.cli.outputs import check_outputs
from radarcal.errors import InputError
from radarcal.readout import format_camera_in_lidar

__all__ = ["lidar_camera"]

LidarEdges = Enum("LidarEdges", {k: k for k in ("planes", "depth", "intensity", "depth+intensity")}, type=str)
ImageEdges = Enum("ImageEdges", {k: k for k in ("lsd", "canny", "auto")}, type=str)
RefineMethod = Enum("RefineMethod", {k: k for k in ("matches", "dense")}, type=str)


def _numbers(text: str | None, what: str) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(t) for t in text.replace("x", ",").split(","))
    except ValueError:
        raise InputError(what, f"expected 2 comma-separated numbers, got {text!r}") from None
    if len(vals) != 2 or not all(v > 0 for v in vals):
        raise InputError(what, f"expected 2 positive numbers, got {text!r}")
    return vals


def lidar_camera(
    bundle: BundleOpt = ...,
    camera: str = typer.Option(None, "--camera", help="Camera name in the bundle [default: the bundle's only camera]."),
    lidar: str = typer.Option("lidar0", "--lidar", help="LiDAR name (frame) in the bundle."),
    images: list[Path] = typer.Option([], "--image", help="Image (raw, distorted); repeat for several scenes, paired in order with --cloud."),
    clouds: list[Path] = typer.Option([], "--cloud", help="Point cloud (PCD/PLY/KITTI .bin/.npy) in the LiDAR frame, or a ROS bag whose clouds (one topic) are merged; one per --image."),
    cloud_topic: CloudTopicOpt = None,
    init: Path = typer.Option(None, "--init", help="Initial T_cam_lidar: 4x4 JSON/text or 'x y z roll pitch yaw' (m, deg)."),
    corners: Path = typer.Option(None, "--corners", help="Manual correspondences CSV x,y,z,u,v[,view]."),
    board: str = typer.Option(None, "--board", help="Board size WIDTH,HEIGHT in m: detect boards in the clouds (RANSAC plane, rectangle, 4 corners)."),
    board_uv: Path = typer.Option(None, "--board-uv", help="Clicked image corners of the boards: CSV u,v[,view], 4 rows per board, any order."),
    board_squares: str = typer.Option(None, "--board-squares", help="NX,NY squares of a chessboard painted edge to edge on the board: find its image corners automatically."),
    refine: bool = typer.Option(False, "--refine", help="Targetless edge-alignment refinement (multi-scene when several pairs)."),
    lidar_edges: LidarEdges = typer.Option("planes", "--lidar-edges", help="planes (plane intersections; dense Livox clouds), depth (range jumps along scan lines), intensity (reflectivity steps along scan lines: lane markings; single spinning sweeps, best with --rotation-only --image-edges canny) or depth+intensity."),
    intensity_edges: bool = typer.Option(True, "--intensity-edges/--no-intensity-edges", help="With --lidar-edges planes: also align reflectivity edges of the dense cloud (paint, markings) when it has intensity."),
    image_edges: ImageEdges = typer.Option("lsd", "--image-edges", help="lsd (straight segments, less clutter), canny, or auto (refine with LSD and with LSD+Canny, keep the pose that aligns better with Canny edges: twice the time; fewer wrong minima on low-contrast 640x512 images, docs/lidar_camera.md)."),
    image_edge_min_px: int = typer.Option(40, "--image-edge-min-px", help="Shortest image edge kept (px); 20 keeps the short lane-marking dashes that --lidar-edges intensity matches."),
    refine_method: RefineMethod = typer.Option("matches", "--refine-method", help="matches (sparse edge matches, default) or dense (LiDAR depth edges scored on the blurred image gradient; cluttered real scenes with few plane-plane edges)."),
    voxel: float = typer.Option(0.5, "--voxel", help="Voxel size (m) for LiDAR plane fitting (0.3-0.5 dense Livox, 1.0 sparse spinning)."),
    search_deg: float = typer.Option(6.0, "--search-deg", help="Half-width of the coarse rotation search (deg; 0 disables)."),
    max_range: float = typer.Option(60.0, "--max-range", help="Ignore LiDAR points farther than this (m) for edges."),
    trans_prior: float = typer.Option(0.3, "--trans-prior", help="Sigma (m) of a prior holding the translation near the initial guess during --refine (0: none)."),
    rotation_only: bool = typer.Option(False, "--rotation-only", help="Refine the rotation only (translation measured elsewhere)."),
    overlay: Path = typer.Option(None, "--overlay", help="Write the first cloud over the first image, before | after (PNG)."),
    max_pnp_rms: float = typer.Option(3.0, "--max-pnp-rms", help="Refuse a corners/boards pose whose reprojection RMS over the kept correspondences exceeds this (px)."),
    force: bool = typer.Option(False, "--force", help="Store the result even when the refinement did not converge or the PnP residuals say it is wrong."),
    ui: str = typer.Option(None, "--ui", help="Nudge the initial pose by eye first: the first cloud over the first image in the browser on [HOST:]PORT (docs/console.md)."),
    as_json: JsonOpt = False,
) -> None:
    """Calibrate T_cam_lidar: manual corners / boards (PnP) and/or targetless edge refinement."""
    from radarcal.bundle import load_or_create_bundle
    from radarcal.extrinsics.lidar_camera_calibrate import LidarCameraOptions, calibrate, read_inputs

    t_start = time.perf_counter()
    squares = _numbers(board_squares, "--board-squares")
    opts = LidarCameraOptions(board_size=_numbers(board, "--board"), board_squares=None if squares is None else (int(squares[0]), int(squares[1])), refine=refine,
                              refine_method=refine_method.value, lidar_edges=lidar_edges.value, intensity_edges=intensity_edges, image_edges=image_edges.value,
                              image_edge_min_px=image_edge_min_px, voxel=voxel, search_deg=search_deg, max_range=max_range, trans_prior=trans_prior,
                              rotation_only=rotation_only, max_pnp_rms=max_pnp_rms)
    b = load_or_create_bundle(bundle)
    check_outputs(bundle, [("overlay", overlay)], b, inputs=[*images, *clouds, init, corners, board_uv])
    inp = read_inputs(b, camera, lidar, images, clouds, cloud_topic, init, corners, board_uv, opts)
    if ui is not None:  # the operator nudges T_init by eye (radarcal/extrinsics/nudge_ui.py); the rest runs from it unchanged
        if not inp.images:
            raise InputError("--ui", "needs an --image/--cloud pair (the cloud is drawn over the image)")
        from radarcal.extrinsics.nudge_ui import nudge_in_browser

        inp.T_init = nudge_in_browser(inp.images[0], inp.camera, inp.clouds[0].points, inp.T_init, ui, max_range=max_range)
        inp.init_source = f"nudged in the browser from {inp.init_source}"
    res = calibrate(inp, opts, status=err_console.status)
    summary = res.summary()
    if overlay is not None and inp.images:
        res.write_overlay(overlay)
        summary["overlay"] = str(overlay)
    summary["stored"] = not res.refused or force
    if summary["stored"]:
        summary["derived"] = res.store(b, bundle, command_line(), force)
    summary["seconds"] = time.perf_counter() - t_start
    emit(summary, as_json, lambda s: _human(s, bundle))
    if res.refused and not force:
        raise typer.Exit(1)


def _human(s: dict, bundle: Path) -> None:
    x, y, z = s["xyz_m"]
    r, p_, yw = s["rpy_deg"]
    typer.echo(f"T_{s['camera']}_{s['lidar']} [{s['method']}]: xyz=({x:.4f}, {y:.4f}, {z:.4f}) m  rpy=({r:.3f}, {p_:.3f}, {yw:.3f}) deg")
    typer.echo(f"  {format_camera_in_lidar(s['T_cam_lidar'])}")
    deg, m = s["moved_from_init_deg_m"]
    typer.echo(f"  rotated {deg:.3f} deg from the initial guess ({s['init']}); the camera centre is kept (--rotation-only)" if s["rotation_only"]
               else f"  moved {deg:.3f} deg, camera centre {m * 100:.1f} cm from the initial guess ({s['init']})")
    if "pnp" in s:
        q = s["pnp"]
        typer.echo(f"  PnP: rms {q['rms_px']:.2f} px over {len(q['residuals_px']) - len(q['flagged_rows'])} picks; flagged rows {list(map(int, q['flagged_rows']))}; "
                   f"sigma rot {np.array2string(np.asarray(q['sigma_rot_deg']), precision=3)} deg, trans {np.array2string(np.asarray(q['sigma_trans_m']) * 100, precision=2)} cm")
    if "refine_dense" in s:
        q = s["refine_dense"]
        typer.echo(f"  dense: {q['message']}")
        typer.echo(f"  dense score {q['dense_score_before']:.4f} -> {q['dense_score_after']:.4f} (higher = better); edge score {q['edge_score_before_px']:.2f} -> {q['edge_score_after_px']:.2f} px; "
                   f"{q['edge_points']} LiDAR edge points")
    if "refine" in s:
        q = s["refine"]
        typer.echo(f"  edges: {q['message']}")
        if "image_edges_choice" in s:
            c = s["image_edges_choice"]
            typer.echo(f"  image edges: {c['chosen']} kept (alignment cost on Canny edges " + ", ".join(f"{k} {v:.2f}" for k, v in c["canny_alignment_cost_px2"].items()) + " px^2)")
        typer.echo(f"  edge score {q['edge_score_before_px']:.2f} -> {q['edge_score_after_px']:.2f} px; sigma {_sigma_text(q['sigma_rot_deg'], q['sigma_trans_m'], s['rotation_only'])} "
                   f"(lower bound); edge-direction spread {q['observability']['direction_spread']:.2f}")
        typer.echo(f"  block-bootstrap sigma {_sigma_text(q['sigma_bootstrap_rot_deg'], q['sigma_bootstrap_trans_m'], s['rotation_only'])} (edge stretches resampled, one image region left out, equally good restarts, a shared-bias floor)")
    for w in s["warnings"]:
        typer.echo(f"  warning: {w}")
    for d in s.get("derived", []):
        typer.echo(f"  {d}")
    if s.get("overlay"):
        typer.echo(f"  overlay: {s['overlay']}")
    typer.echo(f"  {'stored in ' + str(bundle) if s['stored'] else 'NOT stored (' + '; '.join(s['refused']) + '; --force to store anyway)'}  ({s['seconds']:.1f} s)")


def _sigma_text(rot_deg, trans_m, rotation_only: bool) -> str:
    """σ of the pose for people: a value that is not finite or beyond 10 deg / 1 m says 'unobserved' (the data do not
    constrain that direction) instead of a huge number; no translation σ for a rotation-only solve."""
    def part(values, scale, limit, unit, digits):
        v = np.asarray(values, float) * scale
        return "[" + " ".join("unobserved" if not np.isfinite(x) or x > limit else f"{x:.{digits}f}" for x in v) + f"] {unit}"

    rot = "rot " + part(rot_deg, 1.0, 10.0, "deg", 3)
    return rot if rotation_only else rot + ", trans " + part(trans_m, 100.0, 100.0, "cm", 2)

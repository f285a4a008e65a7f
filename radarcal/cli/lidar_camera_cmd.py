"""``radarcal lidar-camera``: LiDAR -> camera extrinsics from manual picks / boards, refined by edge alignment."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import typer

from radarcal import geometry
from radarcal.bundle import Provenance, hash_inputs, load_or_create_bundle, save_bundle
from radarcal.cli.common import BundleOpt, CloudTopicOpt, JsonOpt, command_line, emit, err_console
from radarcal.cli.outputs import check_outputs
from radarcal.errors import InputError
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.readout import camera_in_lidar, format_camera_in_lidar

__all__ = ["lidar_camera"]


def _pair_list(text: str | None, n: int, what: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(t) for t in text.replace("x", ",").split(","))
    except ValueError:
        raise InputError(what, f"expected {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(v > 0 for v in vals):
        raise InputError(what, f"expected {n} positive numbers, got {text!r}")
    return vals


def lidar_camera(
    bundle: BundleOpt = ...,
    camera: str = typer.Option("cam0", "--camera", help="Camera name in the bundle."),
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
    lidar_edges_kind: str = typer.Option("planes", "--lidar-edges", help="planes (plane intersections; dense Livox clouds), depth (range jumps along scan lines), intensity (reflectivity steps along scan lines: lane markings; single spinning sweeps, best with --rotation-only --image-edges canny) or depth+intensity."),
    intensity_edges: bool = typer.Option(True, "--intensity-edges/--no-intensity-edges", help="With --lidar-edges planes: also align reflectivity edges of the dense cloud (paint, markings) when it has intensity."),
    image_edges_kind: str = typer.Option("lsd", "--image-edges", help="lsd (straight segments, less clutter) or canny."),
    image_edge_min_px: int = typer.Option(40, "--image-edge-min-px", help="Shortest image edge kept (px); 20 keeps the short lane-marking dashes that --lidar-edges intensity matches."),
    refine_method: str = typer.Option("matches", "--refine-method", help="matches (sparse edge matches, default) or dense (LiDAR depth edges scored on the blurred image gradient; cluttered real scenes with few plane-plane edges)."),
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
    from radarcal.extrinsics import lidar_camera as lc
    from radarcal.io import read_image, read_transform
    from radarcal.io.cloud_sources import read_scene_cloud
    from radarcal.io.corners_csv import read_corners_csv, read_uv_csv
    from radarcal.synth.lidar_camera import MOUNT_R_CAM_LIDAR

    t_start = time.perf_counter()
    if len(images) != len(clouds):
        raise InputError("--image/--cloud", f"give one --cloud per --image (got {len(images)} images, {len(clouds)} clouds)")
    if not (corners or board or refine):
        raise InputError("lidar-camera", "nothing to solve: give --corners, --board or --refine")
    if (board or refine) and not images:
        raise InputError("--image/--cloud", "--board and --refine need at least one --image/--cloud pair")
    if board and not (board_uv or board_squares):
        raise InputError("--board", "pair the cloud boards with image corners: give --board-uv FILE or --board-squares NX,NY")
    board_size = _pair_list(board, 2, "--board")
    squares = _pair_list(board_squares, 2, "--board-squares")
    b = load_or_create_bundle(bundle)
    check_outputs(bundle, [("overlay", overlay)], b, inputs=[*images, *clouds, init, corners, board_uv])
    cam = b.camera(camera)
    imgs = [read_image(p) for p in images]
    for p, im in zip(images, imgs):
        if (im.shape[1], im.shape[0]) != cam.image_size:
            raise InputError(p, f"image is {im.shape[1]}x{im.shape[0]} but camera {camera!r} in the bundle is {cam.width}x{cam.height}")
    clds = [read_scene_cloud(p, cloud_topic) for p in clouds]
    for p, c in zip(clouds, clds):
        if len(c) < 100:
            raise InputError(p, f"only {len(c)} points")

    summary: dict = {"camera": camera, "lidar": lidar, "pairs": [[str(i), str(c)] for i, c in zip(images, clouds)], "warnings": []}
    if init is not None:
        T0 = read_transform(init)
        init_src = str(init)
    else:
        T0 = geometry.make_T(MOUNT_R_CAM_LIDAR, np.zeros(3))
        init_src = "default mounting (LiDAR x forward = camera z)"
    if ui is not None:  # the operator nudges T0 by eye (radarcal/extrinsics/nudge_ui.py); the rest runs from it unchanged
        if not imgs:
            raise InputError("--ui", "needs an --image/--cloud pair (the cloud is drawn over the image)")
        from radarcal.extrinsics.nudge_ui import nudge_in_browser

        T0 = nudge_in_browser(imgs[0], cam, clds[0].points, T0, ui, max_range=max_range)
        init_src = f"nudged in the browser from {init_src}"
    summary["init"] = init_src
    T = T0
    method = []
    residual: dict = {}
    sigma: dict = {}
    refusals: list[str] = []  # what the tool's own checks say is wrong with the result (not stored without --force)
    sess = LidarCameraSession(T_init=T0, camera=camera, lidar=lidar)  # what the report draws

    # ---- manual: picks and/or boards
    P_all, U_all, G_all = [], [], []  # groups: rows that stand or fall together (one board's 4 corners)
    if corners is not None:
        p, uv, view = read_corners_csv(corners)
        P_all.append(p)
        U_all.append(uv)
        G_all.append(-1 - np.arange(len(p)))  # a clicked pick stands alone
    n_boards = 0
    if board_size is not None:
        uv_click, uv_view = (read_uv_csv(board_uv) if board_uv else (None, None))
        for k, (im, c) in enumerate(zip(imgs, clds)):
            found = lc.detect_boards_in_cloud(c.points, board_size)
            if uv_click is not None:
                sel = uv_click[uv_view == k]
                img_boards = [sel[i : i + 4] for i in range(0, len(sel), 4)]
            else:
                img_boards = lc.detect_chessboards_in_image(im, cam, (int(squares[0]), int(squares[1])))
            summary.setdefault("boards", []).append({"view": k, "in_cloud": len(found), "in_image": len(img_boards)})
            if not found or not img_boards:
                summary["warnings"].append(f"view {k}: {len(found)} board(s) in the cloud, {len(img_boards)} in the image: skipped")
                continue
            try:
                Pb, Ub, w = lc.pair_boards(cam, [f.corners_lidar for f in found], img_boards, T_prior=T0)
            except ValueError as e:
                summary["warnings"].append(f"view {k}: {e}")
                continue
            summary["warnings"] += [f"view {k}: {x}" for x in w]
            P_all.append(Pb)
            U_all.append(Ub)
            G_all.append(n_boards + np.arange(len(Pb)) // 4)
            n_boards += len(Pb) // 4
    if P_all:
        P, U, G = np.vstack(P_all), np.vstack(U_all), np.concatenate(G_all)
        if len(P) < 4:
            raise InputError(corners or "--board", f"need at least 4 correspondences, got {len(P)}")
        try:
            sol = lc.solve_corners(cam, P, U, groups=G, max_rms_px=max_pnp_rms)
        except ValueError as e:
            raise InputError(corners or "--board", str(e)) from None
        if not sol.ok:
            refusals.append(f"PnP: {sol.verdict}")
        T = sol.T_cam_lidar
        method.append(sol.method)
        summary["warnings"] += sol.warnings
        residual.update({"pnp_rms_px": sol.rms_px, "pnp_n_used": sol.n_used, "pnp_n_flagged": int(sol.outliers.sum())})
        sigma.update({"pnp_rot_deg": np.degrees(sol.sigma[:3]).tolist(), "pnp_trans_m": sol.sigma[3:].tolist()})
        summary["pnp"] = {"rms_px": sol.rms_px, "residuals_px": sol.residuals_px, "flagged_rows": np.flatnonzero(sol.outliers), "sigma_rot_deg": np.degrees(sol.sigma[:3]), "sigma_trans_m": sol.sigma[3:],
                          "ok": sol.ok, "verdict": sol.verdict}
        sess.pnp_p_lidar, sess.pnp_uv, sess.pnp_residuals_uv, sess.pnp_flagged, sess.T_pnp = P, U, sol.residuals_uv, sol.outliers, T

    # ---- targetless refinement
    converged = True
    if refine:
        from radarcal.extrinsics.edges import SCAN_EDGE_KINDS, crop_to_camera, image_edges, lidar_edges, lidar_intensity_edges, lidar_scan_edges, merge_edges
        from radarcal.extrinsics.refine import PARAM_NAMES, EdgeScene, RefineOptions, refine_edges

        if refine_method not in ("matches", "dense"):
            raise InputError("--refine-method", f"expected 'matches' or 'dense', got {refine_method!r}")
        if lidar_edges_kind not in ("planes", *SCAN_EDGE_KINDS):
            raise InputError("--lidar-edges", f"expected one of planes, {', '.join(SCAN_EDGE_KINDS)}; got {lidar_edges_kind!r}")
        if image_edge_min_px < 1:
            raise InputError("--image-edge-min-px", f"expected a positive length, got {image_edge_min_px}")
        if image_edges_kind not in ("lsd", "canny"):
            raise InputError("--image-edges", f"expected 'lsd' or 'canny', got {image_edges_kind!r}")
        if refine_method == "dense":
            converged, T = _refine_dense(cam, imgs, clds, T, max_range, search_deg, rotation_only, voxel, image_edges_kind, summary, residual, sess)
            method.append("dense-edge-correlation")
    if refine and refine_method == "matches":
        scenes = []
        with err_console.status("extracting edges"):
            for p, im, c in zip(clouds, imgs, clds):
                view = crop_to_camera(c.points, cam, T, margin=0.3)  # a spinning sweep is mostly out of view
                pts = c.points[view]
                if lidar_edges_kind == "planes":
                    le = lidar_edges(pts, voxel=voxel, max_range=max_range)
                    if intensity_edges and c.intensity is not None:
                        li = lidar_intensity_edges(pts, np.asarray(c.intensity)[view], max_range=max_range)
                        summary.setdefault("intensity_edge_samples", []).append(len(li.points))
                        le = merge_edges(le, li)
                else:
                    if "intensity" in lidar_edges_kind and c.intensity is None:
                        raise InputError(p, f"--lidar-edges {lidar_edges_kind} needs an intensity (reflectivity) field; the cloud has none")
                    le = lidar_scan_edges(pts, None if c.intensity is None else c.intensity[view], None if c.ring is None else c.ring[view], lidar_edges_kind, max_range)
                if len(le.points) < 30:
                    advice = f"try --voxel {voxel * 2:g}" if lidar_edges_kind == "planes" else "a single sweep has few reflectivity steps in view: give more --image/--cloud scenes"
                    summary["warnings"].append(f"{p}: only {len(le.points)} LiDAR edge samples ({advice})")
                scenes.append(EdgeScene(cam, le, image_edges(im, min_length=image_edge_min_px, method=image_edges_kind)))
        opts = RefineOptions(coarse_search_deg=search_deg, translation_prior_m=trans_prior, fix_translation=rotation_only)
        if "intensity" in lidar_edges_kind:
            # tens of reflectivity edges per sweep, not thousands: verdict thresholds measured on opencalib_road_64beam
            # (right results matched 22-36 % of the samples in view, wrong minima 13-19 %)
            opts.min_matches, opts.min_match_fraction = 20, 0.2
        with err_console.status("refining"):
            res = refine_edges(scenes, T, opts)
        converged = res.converged
        T = res.T_cam_lidar
        method.append("edge-alignment")
        summary["warnings"] += res.warnings
        summary["refine"] = {"converged": res.converged, "message": res.message, "rms_px": res.rms_px, "n_matches": res.n_matches, "edge_score_before_px": res.score_before,
                             "edge_score_after_px": res.score_after, "sigma_rot_deg": np.degrees(res.sigma[:3]), "sigma_trans_m": res.sigma[3:], "observability": res.observability,
                             "sigma_bootstrap_rot_deg": np.degrees(res.sigma_bootstrap[:3]), "sigma_bootstrap_trans_m": res.sigma_bootstrap[3:],
                             "lidar_edge_samples": [len(s.lidar.points) for s in scenes]}
        residual.update({"edge_rms_px": res.rms_px, "edge_matches": res.n_matches, "edge_score_px": res.score_after, "edge_score_before_px": res.score_before})
        sigma.update({"edge_rot_deg": np.degrees(res.sigma[:3]).tolist(), "edge_trans_m": res.sigma[3:].tolist()})
        if np.all(np.isfinite(res.sigma_bootstrap)):
            sigma.update({"edge_bootstrap_rot_deg": np.degrees(res.sigma_bootstrap[:3]).tolist(), "edge_bootstrap_trans_m": res.sigma_bootstrap[3:].tolist()})
        sess.residuals_before, sess.residuals_after, sess.scene_matches = res.residuals_before, res.residuals_after, dict(res.matches)
        sess.profile_offsets = np.stack([np.asarray(res.profiles[n][0], float) for n in PARAM_NAMES])
        sess.profile_costs = np.stack([np.asarray(res.profiles[n][1], float) for n in PARAM_NAMES])
        sess.robust_scale_px = float(opts.loss_scale_px)

    moved = (geometry.pose_error(T, T0)[0], float(np.linalg.norm(camera_in_lidar(T)["position_m"] - camera_in_lidar(T0)["position_m"])))  # deg, camera centre m
    if not converged and refine and "refine" in summary and summary["refine"]["n_matches"] < 100:
        summary["warnings"].append(f"these {len(clouds)} scene(s) do not constrain the extrinsic ({summary['refine']['n_matches']} edge matches): keep the initial "
                                   f"extrinsic ({init_src}; `radarcal bundle set-transform` stores it) or add scenes with more edges (--image/--cloud pairs)")
    xyz_rpy = geometry.T_to_xyz_rpy_deg(T)
    summary.update({"T_cam_lidar": T, "xyz_m": xyz_rpy[:3], "rpy_deg": xyz_rpy[3:], "moved_from_init_deg_m": list(moved), "method": " + ".join(method), "stored": False})
    if overlay is not None and imgs:
        import cv2

        from radarcal.extrinsics.overlay import overlay_cloud, side_by_side

        pts = clds[0].points
        pts = pts[np.linalg.norm(pts, axis=1) < max_range]
        img = side_by_side(overlay_cloud(imgs[0], cam, T0, pts, label="before"), overlay_cloud(imgs[0], cam, T, pts, label="after"))
        try:
            written = cv2.imwrite(str(overlay), img)
        except cv2.error:  # no writer for the extension
            written = False
        if not written:
            raise InputError(overlay, "cannot write the overlay image (unknown image extension?)")
        summary["overlay"] = str(overlay)
    if not converged:
        refusals.append("the refinement did not converge")
    summary["refused"] = refusals
    if refusals and force:
        residual["forced"] = list(refusals)  # `bundle validate`, the report and `run` show it
    if not refusals or force:
        inputs = [*images, *clouds] + [p for p in (init, corners, board_uv) if p is not None]
        b.set_transform(camera, lidar, T, method=" + ".join(method), residual=residual, sigma=sigma,
                        provenance=Provenance(command=command_line(), inputs_sha256=hash_inputs(inputs)))
        b.set_sensor(lidar, type=b.sensors.get(lidar, {}).get("type", "lidar"))
        if b.path is None:
            b.path = Path(bundle)
        sess.T_final, sess.init, sess.method, sess.converged, sess.pairs, sess.warnings = T, init_src, " + ".join(method), bool(converged), summary["pairs"], list(summary["warnings"])
        sess.save(b, f"lidar_camera/{camera}_{lidar}")
        save_bundle(b, bundle)
        summary["stored"] = True
    summary["seconds"] = time.perf_counter() - t_start

    def human(s: dict) -> None:
        x, y, z = s["xyz_m"]
        r, p_, yw = s["rpy_deg"]
        typer.echo(f"T_{camera}_{lidar} [{s['method']}]: xyz=({x:.4f}, {y:.4f}, {z:.4f}) m  rpy=({r:.3f}, {p_:.3f}, {yw:.3f}) deg")
        typer.echo(f"  {format_camera_in_lidar(s['T_cam_lidar'])}")
        if rotation_only:
            typer.echo(f"  rotated {s['moved_from_init_deg_m'][0]:.3f} deg from the initial guess ({s['init']}); the camera centre is kept (--rotation-only)")
        else:
            typer.echo(f"  moved {s['moved_from_init_deg_m'][0]:.3f} deg, camera centre {s['moved_from_init_deg_m'][1] * 100:.1f} cm from the initial guess ({s['init']})")
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
            typer.echo(f"  edge score {q['edge_score_before_px']:.2f} -> {q['edge_score_after_px']:.2f} px; sigma {_sigma_text(q['sigma_rot_deg'], q['sigma_trans_m'], rotation_only)} "
                       f"(lower bound); edge-direction spread {q['observability']['direction_spread']:.2f}")
            typer.echo(f"  block-bootstrap sigma {_sigma_text(q['sigma_bootstrap_rot_deg'], q['sigma_bootstrap_trans_m'], rotation_only)} (edge stretches resampled, equally good restarts, a shared-bias floor)")
        for w in s["warnings"]:
            typer.echo(f"  warning: {w}")
        if s.get("overlay"):
            typer.echo(f"  overlay: {s['overlay']}")
        typer.echo(f"  {'stored in ' + str(bundle) if s['stored'] else 'NOT stored (' + '; '.join(s['refused']) + '; --force to store anyway)'}  ({s['seconds']:.1f} s)")

    emit(summary, as_json, human)
    if refusals and not force:
        raise typer.Exit(1)


def _sigma_text(rot_deg, trans_m, rotation_only: bool) -> str:
    """σ of the pose for people: a value that is not finite or beyond 10 deg / 1 m says 'unobserved' (the data do not
    constrain that direction) instead of a huge number; no translation σ for a rotation-only solve."""
    def part(values, scale, limit, unit, digits):
        v = np.asarray(values, float) * scale
        return "[" + " ".join("unobserved" if not np.isfinite(x) or x > limit else f"{x:.{digits}f}" for x in v) + f"] {unit}"

    rot = "rot " + part(rot_deg, 1.0, 10.0, "deg", 3)
    return rot if rotation_only else rot + ", trans " + part(trans_m, 100.0, 100.0, "cm", 2)


def _refine_dense(cam, imgs, clds, T, max_range, search_deg, rotation_only, voxel, image_edges_kind, summary, residual, sess):
    """``--refine-method dense``: all pairs share one T; the sparse method's edge score is reported as the common
    yardstick (before / after)."""
    from radarcal.extrinsics.dense import DenseOptions, DenseScene, image_energy, refine_dense
    from radarcal.extrinsics.edges import crop_to_camera, edge_score, image_edges, lidar_edges

    with err_console.status("dense refinement"):
        scenes, yard = [], []
        for im, c in zip(imgs, clds):
            pts = c.points[crop_to_camera(c.points, cam, T, margin=0.3)].astype(float)
            pts = pts[np.linalg.norm(pts, axis=1) < max_range]
            scenes.append(DenseScene(cam, pts, image_energy(im)))
            yard.append((lidar_edges(pts, voxel=voxel, max_range=max_range), image_edges(im, method=image_edges_kind)))
        res = refine_dense(scenes, T, DenseOptions(coarse_search_deg=min(search_deg, 4.0), fix_translation=rotation_only, max_range_m=max_range))

    def ys(Tx):
        return float(np.mean([edge_score(cam, Tx, le, ie)[0] for le, ie in yard]))

    e0, e1 = ys(T), ys(res.T_cam_lidar)
    summary["refine_dense"] = {"converged": res.converged, "message": res.message, "dense_score_before": res.score_init, "dense_score_after": res.score,
                               "edge_score_before_px": e0, "edge_score_after_px": e1, "edge_points": res.n_edge_points,
                               "restart_spread_deg": res.spread_deg, "restart_spread_m": res.spread_m}
    residual.update({"dense_score": res.score, "dense_score_before": res.score_init, "edge_score_px": e1, "edge_score_before_px": e0,
                     "dense_restart_spread_deg": res.spread_deg, "dense_restart_spread_m": res.spread_m})
    sess.T_dense = res.T_cam_lidar
    return res.converged, res.T_cam_lidar

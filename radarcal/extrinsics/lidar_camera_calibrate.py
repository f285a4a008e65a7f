"""``radarcal lidar-camera`` as one call: :func:`read_inputs` (files -> :class:`LidarCameraInputs`),
``calibrate(inputs, options) -> LidarCameraResult`` (manual picks / boards by PnP, then targetless edge refinement,
sparse or dense) and :meth:`LidarCameraResult.store` (bundle entry ``T_<camera>_<lidar>`` + session file).

Frames: ``T_cam_lidar`` maps LiDAR points (m) into the camera (x right, y down, z forward); pixels px.
Checks that refuse a result (not stored without ``force``): PnP residuals above ``max_pnp_rms`` / the PnP verdict,
and a refinement that did not converge.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.readout import R_CAM_VIEW, camera_in_lidar

__all__ = ["LidarCameraOptions", "LidarCameraInputs", "LidarCameraResult", "read_inputs", "calibrate"]


@dataclass
class LidarCameraOptions:
    board_size: tuple[float, float] | None = None  # --board W,H (m): boards found in the clouds
    board_squares: tuple[int, int] | None = None  # chessboard painted on the board: image corners found automatically
    refine: bool = False
    refine_method: str = "matches"  # matches | dense
    lidar_edges: str = "planes"  # planes | depth | intensity | depth+intensity
    intensity_edges: bool = True
    image_edges: str = "lsd"  # lsd | canny | auto (LSD and LSD+Canny refined, the better on Canny edges kept)
    image_edge_min_px: int = 40
    voxel: float = 0.5
    search_deg: float = 6.0
    max_range: float = 60.0
    trans_prior: float = 0.3
    rotation_only: bool = False
    max_pnp_rms: float = 3.0


@dataclass
class LidarCameraInputs:
    camera_name: str
    lidar: str
    camera: object  # radarcal.Camera
    image_paths: list
    images: list  # BGR / gray arrays
    cloud_paths: list
    clouds: list  # radarcal.io.clouds.Cloud
    T_init: np.ndarray
    init_source: str
    corners: tuple | None = None  # (p_lidar (N,3), uv (N,2)) from --corners
    corners_path: Path | None = None
    board_uv: tuple | None = None  # (uv (4B,2), view (4B,)) from --board-uv
    input_files: list = field(default_factory=list)  # for the provenance hash


def read_inputs(bundle, camera: str | None, lidar: str, images: list[Path], clouds: list[Path], cloud_topic: str | None, init: Path | None,
                corners: Path | None, board_uv: Path | None, options: LidarCameraOptions) -> LidarCameraInputs:
    """Read and check the files of one ``lidar-camera`` run (InputError naming the file or option)."""
    from radarcal.io import read_image, read_transform
    from radarcal.io.cloud_sources import read_scene_cloud
    from radarcal.io.corners_csv import read_corners_csv, read_uv_csv

    o = options
    if len(images) != len(clouds):
        raise InputError("--image/--cloud", f"give one --cloud per --image (got {len(images)} images, {len(clouds)} clouds)")
    if not (corners or o.board_size or o.refine):
        raise InputError("lidar-camera", "nothing to solve: give --corners, --board or --refine")
    if (o.board_size or o.refine) and not images:
        raise InputError("--image/--cloud", "--board and --refine need at least one --image/--cloud pair")
    if o.board_size and not (board_uv or o.board_squares):
        raise InputError("--board", "pair the cloud boards with image corners: give --board-uv FILE or --board-squares NX,NY")
    if o.image_edge_min_px < 1:
        raise InputError("--image-edge-min-px", f"expected a positive length, got {o.image_edge_min_px}")
    camera = bundle.resolve_camera(camera)
    cam = bundle.camera(camera)
    imgs = [read_image(p) for p in images]
    for p, im in zip(images, imgs):
        if (im.shape[1], im.shape[0]) != cam.image_size:
            raise InputError(p, f"image is {im.shape[1]}x{im.shape[0]} but camera {camera!r} in the bundle is {cam.width}x{cam.height}")
    clds = [read_scene_cloud(p, cloud_topic) for p in clouds]
    for p, c in zip(clouds, clds):
        if len(c) < 100:
            raise InputError(p, f"only {len(c)} points")
        if "intensity" in o.lidar_edges and o.refine and o.refine_method == "matches" and c.intensity is None:
            raise InputError(p, f"--lidar-edges {o.lidar_edges} needs an intensity (reflectivity) field; the cloud has none")
    T0, src = (read_transform(init), str(init)) if init is not None else (geometry.make_T(R_CAM_VIEW, np.zeros(3)), "default mounting (LiDAR x forward = camera z)")
    pc = None
    if corners is not None:
        p, uv, _ = read_corners_csv(corners)
        pc = (p, uv)
    files = [*images, *clouds] + [p for p in (init, corners, board_uv) if p is not None]
    return LidarCameraInputs(camera, lidar, cam, list(images), imgs, list(clouds), clds, T0, src, pc, corners, read_uv_csv(board_uv) if board_uv else None, files)


@dataclass
class LidarCameraResult:
    inputs: LidarCameraInputs
    options: LidarCameraOptions
    T_cam_lidar: np.ndarray
    method: list = field(default_factory=list)
    residual: dict = field(default_factory=dict)  # -> the bundle entry
    sigma: dict = field(default_factory=dict)
    refusals: list = field(default_factory=list)  # what the checks say is wrong (not stored without force)
    converged: bool = True
    info: dict = field(default_factory=dict)  # printed / --json: pnp, refine, refine_dense, boards, warnings, ...
    session: LidarCameraSession | None = None

    @property
    def refused(self) -> bool:
        return bool(self.refusals)

    def summary(self) -> dict:
        i, T = self.inputs, self.T_cam_lidar
        moved = (geometry.pose_error(T, i.T_init)[0], float(np.linalg.norm(camera_in_lidar(T)["position_m"] - camera_in_lidar(i.T_init)["position_m"])))
        xyz_rpy = geometry.T_to_xyz_rpy_deg(T)
        return {"camera": i.camera_name, "lidar": i.lidar, "pairs": [[str(a), str(c)] for a, c in zip(i.image_paths, i.cloud_paths)], "init": i.init_source,
                **self.info, "T_cam_lidar": T, "xyz_m": xyz_rpy[:3], "rpy_deg": xyz_rpy[3:], "moved_from_init_deg_m": list(moved), "method": " + ".join(self.method),
                "refused": list(self.refusals), "rotation_only": self.options.rotation_only}

    def write_overlay(self, path: Path) -> None:
        """The first cloud over the first image, before | after (PNG); InputError when it cannot be written."""
        import cv2

        from radarcal.extrinsics.overlay import overlay_cloud, side_by_side

        i = self.inputs
        pts = i.clouds[0].points
        pts = pts[np.linalg.norm(pts, axis=1) < self.options.max_range]
        img = side_by_side(overlay_cloud(i.images[0], i.camera, i.T_init, pts, label="before"), overlay_cloud(i.images[0], i.camera, self.T_cam_lidar, pts, label="after"))
        try:
            written = cv2.imwrite(str(path), img)
        except cv2.error:  # no writer for the extension
            written = False
        if not written:
            raise InputError(path, "cannot write the overlay image (unknown image extension?)")

    def store(self, bundle, bundle_path: Path, command: str, force: bool = False) -> list[str]:
        """Write ``T_<camera>_<lidar>``, the sensor and the session file, refresh the transforms derived through a
        stereo pair, save. Returns the derived-entry changes."""
        from radarcal.bundle import Provenance, hash_inputs, save_bundle
        from radarcal.extrinsics.lidar_camera_chain import refresh_derived

        i, method = self.inputs, " + ".join(self.method)
        residual = dict(self.residual)
        if self.refusals and force:
            residual["forced"] = list(self.refusals)  # `bundle validate`, the report and `run` show it
        bundle.set_transform(i.camera_name, i.lidar, self.T_cam_lidar, method=method, residual=residual, sigma=self.sigma,
                             provenance=Provenance(command=command, inputs_sha256=hash_inputs(i.input_files)))
        bundle.set_sensor(i.lidar, type=bundle.sensors.get(i.lidar, {}).get("type", "lidar"))
        if bundle.path is None:
            bundle.path = Path(bundle_path)
        s = self.session
        s.T_final, s.init, s.method, s.converged, s.warnings = self.T_cam_lidar, i.init_source, method, bool(self.converged), list(self.info["warnings"])
        s.pairs = [[str(a), str(c)] for a, c in zip(i.image_paths, i.cloud_paths)]
        s.save(bundle, f"lidar_camera/{i.camera_name}_{i.lidar}")
        changes = refresh_derived(bundle, command)
        save_bundle(bundle, bundle_path)
        return changes


def _manual(inp: LidarCameraInputs, o: LidarCameraOptions, res: LidarCameraResult) -> None:
    """Picks and / or boards -> PnP (outlier flags, σ)."""
    from radarcal.extrinsics import lidar_camera as lc

    cam, info = inp.camera, res.info
    P_all, U_all, G_all = [], [], []  # groups: rows that stand or fall together (one board's 4 corners)
    if inp.corners is not None:
        P_all.append(inp.corners[0])
        U_all.append(inp.corners[1])
        G_all.append(-1 - np.arange(len(inp.corners[0])))  # a clicked pick stands alone
    n_boards = 0
    if o.board_size is not None:
        uv_click, uv_view = inp.board_uv if inp.board_uv is not None else (None, None)
        for k, (im, c) in enumerate(zip(inp.images, inp.clouds)):
            found = lc.detect_boards_in_cloud(c.points, o.board_size)
            if uv_click is not None:
                sel = uv_click[uv_view == k]
                img_boards = [sel[i : i + 4] for i in range(0, len(sel), 4)]
            else:
                img_boards = lc.detect_chessboards_in_image(im, cam, o.board_squares)
            info.setdefault("boards", []).append({"view": k, "in_cloud": len(found), "in_image": len(img_boards)})
            if not found or not img_boards:
                info["warnings"].append(f"view {k}: {len(found)} board(s) in the cloud, {len(img_boards)} in the image: skipped")
                continue
            try:
                Pb, Ub, w = lc.pair_boards(cam, [f.corners_lidar for f in found], img_boards, T_prior=inp.T_init)
            except ValueError as e:
                info["warnings"].append(f"view {k}: {e}")
                continue
            info["warnings"] += [f"view {k}: {x}" for x in w]
            P_all.append(Pb)
            U_all.append(Ub)
            G_all.append(n_boards + np.arange(len(Pb)) // 4)
            n_boards += len(Pb) // 4
    if not P_all:
        return
    P, U, G = np.vstack(P_all), np.vstack(U_all), np.concatenate(G_all)
    where = inp.corners_path or "--board"
    if len(P) < 4:
        raise InputError(where, f"need at least 4 correspondences, got {len(P)}")
    try:
        sol = lc.solve_corners(cam, P, U, groups=G, max_rms_px=o.max_pnp_rms)
    except ValueError as e:
        raise InputError(where, str(e)) from None
    if not sol.ok:
        res.refusals.append(f"PnP: {sol.verdict}")
    res.T_cam_lidar = sol.T_cam_lidar
    res.method.append(sol.method)
    info["warnings"] += sol.warnings
    res.residual.update({"pnp_rms_px": sol.rms_px, "pnp_n_used": sol.n_used, "pnp_n_flagged": int(sol.outliers.sum())})
    res.sigma.update({"pnp_rot_deg": np.degrees(sol.sigma[:3]).tolist(), "pnp_trans_m": sol.sigma[3:].tolist()})
    info["pnp"] = {"rms_px": sol.rms_px, "residuals_px": sol.residuals_px, "flagged_rows": np.flatnonzero(sol.outliers), "sigma_rot_deg": np.degrees(sol.sigma[:3]),
                   "sigma_trans_m": sol.sigma[3:], "ok": sol.ok, "verdict": sol.verdict}
    s = res.session
    s.pnp_p_lidar, s.pnp_uv, s.pnp_residuals_uv, s.pnp_flagged, s.T_pnp = P, U, sol.residuals_uv, sol.outliers, sol.T_cam_lidar


def _edge_scenes(inp: LidarCameraInputs, o: LidarCameraOptions, T: np.ndarray, info: dict, methods: tuple[str, ...] | None = None) -> dict:
    """{image-edge method: one EdgeScene per image/cloud pair}: the same LiDAR edges (planes [+ reflectivity] or
    scan-line steps) with the image edges of each method (default: ``o.image_edges`` alone)."""
    from radarcal.extrinsics.edges import crop_to_camera, image_edges, lidar_edges, lidar_intensity_edges, lidar_scan_edges, merge_edges
    from radarcal.extrinsics.refine import EdgeScene

    methods = methods or (o.image_edges,)
    scenes: dict = {m: [] for m in methods}
    for p, im, c in zip(inp.cloud_paths, inp.images, inp.clouds):
        view = crop_to_camera(c.points, inp.camera, T, margin=0.3)  # a spinning sweep is mostly out of view
        pts = c.points[view]
        if o.lidar_edges == "planes":
            le = lidar_edges(pts, voxel=o.voxel, max_range=o.max_range)
            if o.intensity_edges and c.intensity is not None:
                li = lidar_intensity_edges(pts, np.asarray(c.intensity)[view], max_range=o.max_range)
                info.setdefault("intensity_edge_samples", []).append(len(li.points))
                le = merge_edges(le, li)
        else:
            le = lidar_scan_edges(pts, None if c.intensity is None else c.intensity[view], None if c.ring is None else c.ring[view], o.lidar_edges, o.max_range)
        if len(le.points) < 30:
            advice = f"try --voxel {o.voxel * 2:g}" if o.lidar_edges == "planes" else "a single sweep has few reflectivity steps in view: give more --image/--cloud scenes"
            info["warnings"].append(f"{p}: only {len(le.points)} LiDAR edge samples ({advice})")
        for m in methods:
            scenes[m].append(EdgeScene(inp.camera, le, image_edges(im, min_length=o.image_edge_min_px, method=m)))
    return scenes


def _refine_matches(inp: LidarCameraInputs, o: LidarCameraOptions, res: LidarCameraResult, status) -> None:
    """Sparse edge matches (``--refine-method matches``): all pairs share one T."""
    from radarcal.extrinsics.refine import PARAM_NAMES, RefineOptions, refine_edges, refine_edges_choosing

    auto = o.image_edges == "auto"
    with status("extracting edges"):
        cand = _edge_scenes(inp, o, res.T_cam_lidar, res.info, ("lsd", "lsd+canny", "canny") if auto else None)
    opts = RefineOptions(coarse_search_deg=o.search_deg, translation_prior_m=o.trans_prior, fix_translation=o.rotation_only)
    if "intensity" in o.lidar_edges:
        # tens of reflectivity edges per sweep, not thousands: verdict thresholds measured on opencalib_road_64beam
        # (right results matched 22-36 % of the samples in view, wrong minima 13-19 %)
        opts.min_matches, opts.min_match_fraction = 20, 0.2
    with status("refining" + (" (LSD and LSD+Canny image edges)" if auto else "")):
        if auto:  # the better pose on Canny edges (every image edge) wins: docs/lidar_camera.md "image edges per scene"
            referee = cand.pop("canny")
            chosen, results, costs = refine_edges_choosing(cand, referee, res.T_cam_lidar, opts)
            r, scenes = results[chosen], cand[chosen]
            res.info["image_edges_choice"] = {"chosen": chosen, "canny_alignment_cost_px2": costs}
        else:
            scenes = cand[o.image_edges]
            r = refine_edges(scenes, res.T_cam_lidar, opts)
    res.converged, res.T_cam_lidar = r.converged, r.T_cam_lidar
    res.method.append("edge-alignment")
    res.info["warnings"] += r.warnings
    res.info["refine"] = {"converged": r.converged, "message": r.message, "rms_px": r.rms_px, "n_matches": r.n_matches, "edge_score_before_px": r.score_before,
                          "edge_score_after_px": r.score_after, "sigma_rot_deg": np.degrees(r.sigma[:3]), "sigma_trans_m": r.sigma[3:], "observability": r.observability,
                          "sigma_bootstrap_rot_deg": np.degrees(r.sigma_bootstrap[:3]), "sigma_bootstrap_trans_m": r.sigma_bootstrap[3:],
                          "lidar_edge_samples": [len(s.lidar.points) for s in scenes]}
    res.residual.update({"edge_rms_px": r.rms_px, "edge_matches": r.n_matches, "edge_score_px": r.score_after, "edge_score_before_px": r.score_before})
    res.sigma.update({"edge_rot_deg": np.degrees(r.sigma[:3]).tolist(), "edge_trans_m": r.sigma[3:].tolist()})
    if np.all(np.isfinite(r.sigma_bootstrap)):
        res.sigma.update({"edge_bootstrap_rot_deg": np.degrees(r.sigma_bootstrap[:3]).tolist(), "edge_bootstrap_trans_m": r.sigma_bootstrap[3:].tolist()})
    s = res.session
    s.residuals_before, s.residuals_after, s.scene_matches = r.residuals_before, r.residuals_after, dict(r.matches)
    s.profile_offsets = np.stack([np.asarray(r.profiles[n][0], float) for n in PARAM_NAMES])
    s.profile_costs = np.stack([np.asarray(r.profiles[n][1], float) for n in PARAM_NAMES])
    s.robust_scale_px = float(opts.loss_scale_px)
    if not r.converged and r.n_matches < 100:
        res.info["warnings"].append(f"these {len(inp.clouds)} scene(s) do not constrain the extrinsic ({r.n_matches} edge matches): keep the initial "
                                    f"extrinsic ({inp.init_source}; `radarcal bundle set-transform` stores it) or add scenes with more edges (--image/--cloud pairs)")


def _refine_dense(inp: LidarCameraInputs, o: LidarCameraOptions, res: LidarCameraResult, status) -> None:
    """``--refine-method dense``: all pairs share one T; the sparse method's edge score is reported as the common
    yardstick (before / after)."""
    from radarcal.extrinsics.dense import DenseOptions, DenseScene, image_energy, refine_dense
    from radarcal.extrinsics.edges import crop_to_camera, edge_score, image_edges, lidar_edges

    cam, T = inp.camera, res.T_cam_lidar
    with status("dense refinement"):
        scenes, yard = [], []
        for im, c in zip(inp.images, inp.clouds):
            pts = c.points[crop_to_camera(c.points, cam, T, margin=0.3)].astype(float)
            pts = pts[np.linalg.norm(pts, axis=1) < o.max_range]
            scenes.append(DenseScene(cam, pts, image_energy(im)))
            yard.append((lidar_edges(pts, voxel=o.voxel, max_range=o.max_range), image_edges(im, method="lsd" if o.image_edges == "auto" else o.image_edges)))
        r = refine_dense(scenes, T, DenseOptions(coarse_search_deg=min(o.search_deg, 4.0), fix_translation=o.rotation_only, max_range_m=o.max_range))

    def yardstick(Tx):
        return float(np.mean([edge_score(cam, Tx, le, ie)[0] for le, ie in yard]))

    e0, e1 = yardstick(T), yardstick(r.T_cam_lidar)
    res.info["refine_dense"] = {"converged": r.converged, "message": r.message, "dense_score_before": r.score_init, "dense_score_after": r.score,
                                "edge_score_before_px": e0, "edge_score_after_px": e1, "edge_points": r.n_edge_points,
                                "restart_spread_deg": r.spread_deg, "restart_spread_m": r.spread_m}
    res.residual.update({"dense_score": r.score, "dense_score_before": r.score_init, "edge_score_px": e1, "edge_score_before_px": e0,
                         "dense_restart_spread_deg": r.spread_deg, "dense_restart_spread_m": r.spread_m})
    res.session.T_dense = r.T_cam_lidar
    res.converged, res.T_cam_lidar = r.converged, r.T_cam_lidar
    res.method.append("dense-edge-correlation")


def calibrate(inputs: LidarCameraInputs, options: LidarCameraOptions | None = None, status: Callable | None = None) -> LidarCameraResult:
    """PnP on picks / boards (when given), then the edge refinement (``options.refine``) from its result.
    ``status(text)``: a context manager shown while a long step runs (default: none)."""
    o = options or LidarCameraOptions()
    status = status or (lambda text: contextlib.nullcontext())
    res = LidarCameraResult(inputs, o, inputs.T_init, info={"warnings": []},
                            session=LidarCameraSession(T_init=inputs.T_init, camera=inputs.camera_name, lidar=inputs.lidar))
    _manual(inputs, o, res)
    if o.refine:
        (_refine_dense if o.refine_method == "dense" else _refine_matches)(inputs, o, res, status)
        if not res.converged:
            res.refusals.append("the refinement did not converge")
    return res

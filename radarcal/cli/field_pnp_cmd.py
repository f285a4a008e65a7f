"""``radarcal field-pnp``: the camera's pose on the field from four (or more) clicked landmarks (docs/field.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console
from radarcal.cli.outputs import check_outputs, input_file
from radarcal.errors import InputError

__all__ = ["field_pnp"]


def _depth_source(bundle, camera: str, lidar: str | None) -> str | None:
    """Name of a LiDAR chained to the camera (the runtime's depth source), or None (ground fallback)."""
    names = [lidar] if lidar else [n for n, m in bundle.sensors.items() if m.get("type") == "lidar"]
    for n in names:
        if n and bundle.has_T(camera, n):
            return n
    return None


def _table(em, which: str) -> list[str]:
    s = em.sigma_lidar if which == "lidar" else em.sigma_ground
    head = "   y\\x " + "".join(f"{x:6.0f}" for x in em.xs)
    rows = [head]
    for j in range(len(em.ys) - 1, -1, -1):
        rows.append(f"{em.ys[j]:6.1f} " + "".join("     ." if not np.isfinite(v) else f"{v:6.2f}" for v in s[j]))
    return rows


def field_pnp(
    bundle: BundleOpt = ...,
    camera: str = typer.Option("cam0", "--camera", help="Camera name in the bundle."),
    field: str = typer.Option(None, "--field", help="Built-in field (rmuc2024) or a YAML/JSON field file [default: the bundle's field, else rmuc2024]."),
    points: Path = typer.Option(None, "--points", help="picks.csv with name,u,v rows (written by the picker when --image is given and the file does not exist)."),
    image: Path = typer.Option(None, "--image", help="Camera image: open the interactive picker (needs a display)."),
    landmarks: str = typer.Option(None, "--landmarks", help="Comma-separated landmarks for the picker [default: four for --side]."),
    side: str = typer.Option("red", "--side", help="Our side (red|blue): picks the picker's default landmarks."),
    click_sigma: float = typer.Option(1.0, "--click-sigma", help="Assumed click noise (px) for σ and the error map."),
    pixel_sigma: float = typer.Option(1.0, "--pixel-sigma", help="Detection pixel noise (px) in the error map."),
    range_sigma: float = typer.Option(0.02, "--range-sigma", help="LiDAR range noise (m) in the error map."),
    max_rms: float = typer.Option(5.0, "--max-rms", help="Reject the pose when the reprojection RMS exceeds this (px)."),
    ransac_px: float = typer.Option(8.0, "--ransac-px", help="Outlier threshold (px) when more than 4 picks are given."),
    grid: float = typer.Option(1.0, "--grid", help="Error-map cell size (m) for the PNG and the session."),
    error_map_png: Path = typer.Option(None, "--error-map", help="Write the localisation error map as a PNG."),
    overlay: Path = typer.Option(None, "--overlay", help="With --image: write the image with the field outline, raised areas and all landmarks projected by the solved pose."),
    depth: str = typer.Option("auto", "--depth", help="Depth source for the printed map: auto (LiDAR if one is chained to the camera) | lidar | ground."),
    lidar: str = typer.Option(None, "--lidar", help="LiDAR sensor name (default: any LiDAR chained to the camera)."),
    ui: str = typer.Option(None, "--ui", help="With --image: click the landmarks in the browser, served on [HOST:]PORT (127.0.0.1 unless a host is given)."),
    as_json: JsonOpt = False,
) -> None:
    """Solve the camera's pose on the field from clicked landmarks; write T_<camera>_field and an error map."""
    from radarcal.bundle import Provenance, hash_inputs, load_bundle, save_bundle
    from radarcal.field import load_field
    from radarcal.io import read_image
    from radarcal.pnp.error_map import error_map
    from radarcal.pnp.field_pnp import FieldPnPError, PnPOptions, solve_field_pnp
    from radarcal.pnp.session import FieldPnPSession
    from radarcal.pnp.picks import DEFAULT_PICKS, has_display, pick_landmarks, read_picks, save_picks

    if overlay is not None and image is None:
        raise InputError("--overlay", "needs --image (the overlay is drawn on it)")
    if depth not in ("auto", "lidar", "ground"):
        raise InputError("--depth", f"expected auto, lidar or ground, got {depth!r}")
    if side not in DEFAULT_PICKS:
        raise InputError("--side", f"expected red or blue, got {side!r}")
    for opt, v in (("--click-sigma", click_sigma), ("--max-rms", max_rms), ("--ransac-px", ransac_px), ("--grid", grid)):
        if not v > 0:
            raise InputError(opt, f"must be > 0, got {v}")
    if image is not None:
        input_file(image, "image")
    b = load_bundle(bundle)
    check_outputs(bundle, [("error map", error_map_png), ("overlay", overlay)], b, inputs=[points, image])
    cam = b.camera(camera)
    if field is not None:
        fm = load_field(field)
        field_src = field
    elif b.field_model:
        fm = b.field()
        field_src = f"bundle ({fm.name})"
    else:
        fm = load_field("rmuc2024")
        field_src = "rmuc2024"

    # --- picks: file, or the interactive picker ---------------------------------------------------------------
    opt = PnPOptions(click_sigma_px=click_sigma, max_rms_px=max_rms, ransac_threshold_px=ransac_px)
    T_nudged = None
    if ui is not None:  # the browser page (radarcal/pnp/ui.py): saving runs the same solver and checks as the CSV path
        if image is None:
            raise InputError("--ui", "needs --image (the camera frame to click on)")
        from radarcal.pnp.ui import pick_in_browser, pose_result

        img = read_image(image)
        if tuple(img.shape[1::-1]) != tuple(cam.image_size):
            raise InputError(image, f"image is {img.shape[1]}x{img.shape[0]} but camera {camera} is {cam.width}x{cam.height}")
        want = [s.strip() for s in landmarks.split(",")] if landmarks else DEFAULT_PICKS[side]
        unknown = [n for n in want if n not in fm.landmarks]
        if unknown:
            raise InputError("--landmarks", f"unknown landmark(s) {', '.join(unknown)} (the field has: {', '.join(sorted(fm.landmarks))})")
        picks_src = points or image.with_suffix(".picks.csv")
        start = dict(zip(*read_picks(points, fm.landmarks))) if points is not None and points.exists() else {}

        def check(names, uv, T_override):
            if np.any(~cam.in_image(uv, margin=-0.5)):
                raise InputError(picks_src, "a pick is outside the image")
            r = solve_field_pnp(cam, fm.landmark_array(names), uv, names, opt, surface_z=fm.surface_z)
            r = pose_result(cam, r, T_override, opt) if T_override is not None else r
            return {"message": f"{len(names)} picks, RMS {r.rms_px:.2f} px -> T_{camera}_field in {bundle}", "rms_px": r.rms_px}

        names, uv, T_nudged = pick_in_browser(img, cam, fm, want, check, ui, T_init=b.T(camera, "field") if b.has_T(camera, "field") else None, options=opt, initial=start)
        save_picks(picks_src, names, uv)
        names, uv = read_picks(picks_src, fm.landmarks)  # from here on exactly the CSV path
        err_console.print(f"wrote {len(names)} picks to {picks_src}")
    elif points is not None and points.exists():
        names, uv = read_picks(points, fm.landmarks)
        picks_src = points
    elif image is not None:
        picks_src = points or image.with_suffix(".picks.csv")
        if not has_display():
            if points is not None or not picks_src.is_file():
                raise InputError("--image", "no usable display for the interactive picker (headless, or no GUI toolkit); click the landmarks elsewhere and pass --points picks.csv (name,u,v rows)")
            err_console.print(f"no usable display for the picker: using the picks saved earlier in {picks_src}")
            names, uv = read_picks(picks_src, fm.landmarks)
        else:
            img = read_image(image)
            want = [s.strip() for s in landmarks.split(",")] if landmarks else DEFAULT_PICKS[side]
            unknown = [n for n in want if n not in fm.landmarks]
            if unknown:
                raise InputError("--landmarks", f"unknown landmark(s) {', '.join(unknown)} (the field has: {', '.join(sorted(fm.landmarks))})")
            check_outputs(bundle, [("picks file", picks_src)], b, inputs=[image])
            names, uv = pick_landmarks(img, want, fm)
            save_picks(picks_src, names, uv)
            err_console.print(f"wrote {len(names)} picks to {picks_src}")
    elif points is not None:
        raise InputError(points, "picks file not found (expected name,u,v rows; or pass --image to click them)")
    else:
        raise InputError("--points", "pass --points picks.csv (name,u,v rows) or --image IMG to click the landmarks")
    if image is not None and image.exists():
        img_size = read_image(image).shape[1::-1]
        if tuple(img_size) != tuple(cam.image_size):
            raise InputError(image, f"image is {img_size[0]}x{img_size[1]} but camera {camera} is {cam.width}x{cam.height}")
    outside = ~cam.in_image(uv, margin=-0.5)
    if np.any(outside):
        raise InputError(picks_src, f"pick {names[int(np.argmax(outside))]} is outside the {cam.width}x{cam.height} image")

    # --- solve ---------------------------------------------------------------------------------------------
    try:
        res = solve_field_pnp(cam, fm.landmark_array(names), uv, names, opt, surface_z=fm.surface_z)
        if T_nudged is not None:
            res = pose_result(cam, res, T_nudged, opt)
    except FieldPnPError as e:
        raise InputError(picks_src, str(e)) from None

    lidar_name = _depth_source(b, camera, lidar)
    if lidar and lidar_name is None:
        raise InputError("--lidar", f"no transform chain between {lidar!r} and {camera!r} in the bundle")
    used = depth if depth != "auto" else ("lidar" if lidar_name else "ground")
    em = error_map(cam, res.T_cam_field, res.cov_pose, fm, step=grid, pixel_sigma=pixel_sigma, range_sigma=range_sigma)
    em_print = em if grid >= 2.0 else error_map(cam, res.T_cam_field, res.cov_pose, fm, step=2.0, pixel_sigma=pixel_sigma, range_sigma=range_sigma)

    # --- figures first (a failure leaves the bundle as it was), then the bundle -----------------------------------
    if error_map_png is not None:
        from radarcal.pnp.figures import save_error_map_png

        try:
            save_error_map_png(error_map_png, em, fm, res.camera_position, names, title=f"{camera} on {fm.name}: 1σ localisation error for {click_sigma:g} px clicks, {pixel_sigma:g} px detections")
        except (ValueError, OSError) as e:  # matplotlib: unknown extension; the file system: full, vanished folder
            raise InputError(error_map_png, f"cannot write the error map ({e})") from None

    if overlay is not None:
        import cv2

        from radarcal.pnp.figures import draw_overlay

        over = draw_overlay(read_image(image), cam, res.T_cam_field, fm, names, res.uv)
        if not cv2.imwrite(str(overlay), over):
            raise InputError(overlay, "cannot write the overlay image (unknown extension or unwritable folder)")

    # --- write the bundle ------------------------------------------------------------------------------------
    per_point = {n: float(np.linalg.norm(r)) for n, r in zip(names, res.residuals_px)}
    prov = Provenance(command=command_line(), inputs_sha256=hash_inputs([picks_src] + ([image] if image else []), extra={"field": fm.to_dict(), "click_sigma": click_sigma, "max_rms": max_rms, "ransac_px": ransac_px}))
    b.set_transform(camera, "field", res.T_cam_field, method=f"field-pnp ({res.method}) on {fm.name}", residual={"rms_px": res.rms_px, "per_point_px": per_point, "n_picks": len(names), "n_inliers": int(res.inliers.sum()), "outliers": [n for n, k in zip(names, res.inliers) if not k]}, sigma=res.sigma, provenance=prov)
    b.field_model = fm.to_dict()
    FieldPnPSession(
        names=np.array(names, dtype=str), uv=res.uv, p_field=res.p_field, residuals_px=res.residuals_px, inliers=res.inliers, T_cam_field=res.T_cam_field,
        cov_pose=res.cov_pose, camera_position=res.camera_position, grid_x=em.xs, grid_y=em.ys, sigma_lidar=em.sigma_lidar, sigma_ground=em.sigma_ground,
        field=fm.name, camera=camera, click_sigma_px=click_sigma, pixel_sigma_px=pixel_sigma, range_sigma_m=range_sigma, rms_px=float(res.rms_px),
        depth_source=used, lidar=lidar_name, image=str(image) if image else "", picks_file=str(picks_src), warnings=list(res.warnings),
    ).save(b, f"field_pnp/{camera}")  # fmt: skip
    save_bundle(b, bundle)
    # --- report ----------------------------------------------------------------------------------------------
    from radarcal import geometry

    T_field_cam = geometry.invert_T(res.T_cam_field)
    xyz_rpy = geometry.T_to_xyz_rpy_deg(T_field_cam)
    summary = {
        "camera": camera,
        "field": fm.name,
        "field_source": field_src,
        "picks": [{"name": n, "u": float(u[0]), "v": float(u[1]), "residual_px": per_point[n], "inlier": bool(k)} for n, u, k in zip(names, res.uv, res.inliers)],
        "rms_px": res.rms_px,
        "T_cam_field": res.T_cam_field,
        "camera_position_m": res.camera_position,
        "camera_rpy_deg": xyz_rpy[3:],
        "sigma": res.sigma,
        "warnings": res.warnings,
        "lidar": lidar_name,
        "depth_source": used,
        "error_map": {"lidar": em.stats("lidar"), "ground": em.stats("ground"), "grid_m": grid, "xs": em.xs, "ys": em.ys, "sigma_lidar": em.sigma_lidar, "sigma_ground": em.sigma_ground},
        "bundle": str(bundle),
        "error_map_png": str(error_map_png) if error_map_png else None,
        "overlay": str(overlay) if overlay else None,
    }

    def human(s: dict) -> None:
        typer.echo(f"field-pnp {camera} on {fm.name}: {len(names)} picks, {int(res.inliers.sum())} inliers, reprojection RMS {res.rms_px:.2f} px")
        for p in s["picks"]:
            typer.echo(f"  {p['name']:<30} u={p['u']:8.2f} v={p['v']:8.2f}  residual {p['residual_px']:6.2f} px{'' if p['inlier'] else '  OUTLIER'}")
        c, sc = res.camera_position, res.sigma["camera_position_m"]
        typer.echo(f"camera on the field: x={c[0]:.3f} y={c[1]:.3f} z={c[2]:.3f} m (1σ {sc[0]:.3f} {sc[1]:.3f} {sc[2]:.3f} m for {click_sigma:g} px clicks)")
        typer.echo(f"  roll/pitch/yaw of T_field_{camera}: {xyz_rpy[3]:.2f} {xyz_rpy[4]:.2f} {xyz_rpy[5]:.2f} deg; rotation 1σ {np.linalg.norm(res.sigma['rot_deg']):.3f} deg")
        for w in res.warnings:
            typer.echo(f"  warning: {w}")
        chain = f"; T_field_{lidar_name} via T_{camera}_{lidar_name}" if lidar_name else ""
        typer.echo(f"wrote T_{camera}_field to {bundle}{chain}")
        label = "LiDAR depth" if used == "lidar" else "ground-ray fallback (no LiDAR chained to the camera)" if lidar_name is None else "ground-ray fallback"
        typer.echo(f"expected 1σ localisation error (m) — {label}; {click_sigma:g} px clicks, {pixel_sigma:g} px detections; '.' = not in view")
        for row in _table(em_print, used):
            typer.echo("  " + row)
        for which, name in (("lidar", "LiDAR depth"), ("ground", "ground fallback")):
            st = em.stats(which)
            if st["visible_cells"]:
                typer.echo(f"  {name:<16} median {st['median_m']:.3f} m, 90% {st['p90_m']:.3f} m, max {st['max_m']:.3f} m over {st['visible_cells']} visible {grid:g} m cells")
        if error_map_png:
            typer.echo(f"error map: {error_map_png}")
        if overlay:
            typer.echo(f"overlay: {overlay}")

    emit(summary, as_json, human)

"""``radarcal field-pnp``: the camera's pose on the field from four (or more) clicked landmarks (docs/field.md; the
work is :func:`radarcal.pnp.calibrate.calibrate`)."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import numpy as np
import typer

from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console
from radarcal.cli.outputs import check_outputs, input_file
from radarcal.errors import InputError

__all__ = ["field_pnp"]

Side = Enum("Side", {k: k for k in ("red", "blue")}, type=str)
Depth = Enum("Depth", {k: k for k in ("auto", "lidar", "ground")}, type=str)


def field_pnp(
    bundle: BundleOpt = ...,
    camera: str = typer.Option(None, "--camera", help="Camera name in the bundle [default: the bundle's only camera]."),
    field: str = typer.Option(None, "--field", help="Built-in field (rmuc2024) or a YAML/JSON field file [default: the bundle's field, else rmuc2024]."),
    points: Path = typer.Option(None, "--points", help="picks.csv with name,u,v rows (written by the picker when --image is given and the file does not exist)."),
    image: Path = typer.Option(None, "--image", help="Camera image: open the interactive picker (needs a display)."),
    landmarks: str = typer.Option(None, "--landmarks", help="Comma-separated landmarks for the picker [default: four for --side]."),
    side: Side = typer.Option("red", "--side", help="Our side (red|blue): picks the picker's default landmarks."),
    click_sigma: float = typer.Option(1.0, "--click-sigma", help="Assumed click noise (px) for σ and the error map."),
    pixel_sigma: float = typer.Option(1.0, "--pixel-sigma", help="Detection pixel noise (px) in the error map."),
    range_sigma: float = typer.Option(0.02, "--range-sigma", help="LiDAR range noise (m) in the error map."),
    max_rms: float = typer.Option(5.0, "--max-rms", help="Reject the pose when the reprojection RMS exceeds this (px)."),
    ransac_px: float = typer.Option(8.0, "--ransac-px", help="Outlier threshold (px) when more than 4 picks are given."),
    grid: float = typer.Option(1.0, "--grid", help="Error-map cell size (m) for the PNG and the session."),
    error_map_png: Path = typer.Option(None, "--error-map", help="Write the localisation error map as a PNG."),
    overlay: Path = typer.Option(None, "--overlay", help="With --image: write the image with the field outline, raised areas and all landmarks projected by the solved pose."),
    depth: Depth = typer.Option("auto", "--depth", help="Depth source for the printed map: auto (LiDAR if one is chained to the camera) | lidar | ground."),
    lidar: str = typer.Option(None, "--lidar", help="LiDAR sensor name (default: any LiDAR chained to the camera)."),
    ui: str = typer.Option(None, "--ui", help="With --image: click the landmarks in the browser, served on [HOST:]PORT (127.0.0.1 unless a host is given)."),
    as_json: JsonOpt = False,
) -> None:
    """Solve the camera's pose on the field from clicked landmarks; write T_<camera>_field and an error map."""
    from radarcal.bundle import load_bundle
    from radarcal.pnp.calibrate import FieldPnPOptions, calibrate, resolve_field
    from radarcal.pnp.pick_inputs import acquire_picks

    if overlay is not None and image is None:
        raise InputError("--overlay", "needs --image (the overlay is drawn on it)")
    opts = FieldPnPOptions(click_sigma, pixel_sigma, range_sigma, max_rms, ransac_px, grid, depth.value, lidar)
    popt = opts.pnp()
    if image is not None:
        input_file(image, "image")
    b = load_bundle(bundle)
    check_outputs(bundle, [("error map", error_map_png), ("overlay", overlay)], b, inputs=[points, image])
    camera = b.resolve_camera(camera)
    cam = b.camera(camera)
    fm, field_src = resolve_field(b, field)

    def check(names, uv, T_override):  # a save in the browser: the same solver and checks as the CSV path
        r = calibrate(b, camera, fm, field_src, names, uv, points or image.with_suffix(".picks.csv"), opts, T_override).result
        return {"message": f"{len(names)} picks, RMS {r.rms_px:.2f} px -> T_{camera}_field in {bundle}", "rms_px": r.rms_px}

    picks = acquire_picks(cam, camera, fm, points, image, landmarks, side.value, ui, check, lambda p: check_outputs(bundle, [("picks file", p)], b, inputs=[image]),
                          T_init=b.T(camera, "field") if b.has_T(camera, "field") else None, options=popt, log=err_console.print)
    cal = calibrate(b, camera, fm, field_src, picks.names, picks.uv, picks.source, opts, picks.T_nudged, image)
    cal.write_figures(error_map_png, overlay)  # figures first: a failure leaves the bundle as it was
    derived = cal.store(b, bundle, command_line())
    summary = {**cal.summary(), "derived": derived, "bundle": str(bundle), "error_map_png": str(error_map_png) if error_map_png else None, "overlay": str(overlay) if overlay else None}
    emit(summary, as_json, lambda s: _human(s, cal))


def _table(em, which: str) -> list[str]:
    s = em.sigma_lidar if which == "lidar" else em.sigma_ground
    rows = ["   y\\x " + "".join(f"{x:6.0f}" for x in em.xs)]
    for j in range(len(em.ys) - 1, -1, -1):
        rows.append(f"{em.ys[j]:6.1f} " + "".join("     ." if not np.isfinite(v) else f"{v:6.2f}" for v in s[j]))
    return rows


def _human(s: dict, cal) -> None:
    cam, lidar, used, cs, ps = s["camera"], s["lidar"], s["depth_source"], s["click_sigma_px"], s["pixel_sigma_px"]
    typer.echo(f"field-pnp {cam} on {s['field']}: {len(s['picks'])} picks, {s['n_inliers']} inliers, reprojection RMS {s['rms_px']:.2f} px")
    for p in s["picks"]:
        typer.echo(f"  {p['name']:<30} u={p['u']:8.2f} v={p['v']:8.2f}  residual {p['residual_px']:6.2f} px{'' if p['inlier'] else '  OUTLIER'}")
    c, sc, rpy = s["camera_position_m"], s["sigma"]["camera_position_m"], s["camera_rpy_deg"]
    typer.echo(f"camera on the field: x={c[0]:.3f} y={c[1]:.3f} z={c[2]:.3f} m (1σ {sc[0]:.3f} {sc[1]:.3f} {sc[2]:.3f} m for {cs:g} px clicks)")
    typer.echo(f"  roll/pitch/yaw of T_field_{cam}: {rpy[0]:.2f} {rpy[1]:.2f} {rpy[2]:.2f} deg; rotation 1σ {np.linalg.norm(s['sigma']['rot_deg']):.3f} deg")
    for w in s["warnings"]:
        typer.echo(f"  warning: {w}")
    typer.echo(f"wrote T_{cam}_field to {s['bundle']}" + (f"; T_field_{lidar} via T_{cam}_{lidar}" if lidar else ""))
    for d in s["derived"]:
        typer.echo(f"  {d}")
    label = "LiDAR depth" if used == "lidar" else "ground-ray fallback (no LiDAR chained to the camera)" if lidar is None else "ground-ray fallback"
    typer.echo(f"expected 1σ localisation error (m) — {label}; {cs:g} px clicks, {ps:g} px detections; '.' = not in view")
    for row in _table(cal.error_map_print, used):
        typer.echo("  " + row)
    for which, name in (("lidar", "LiDAR depth"), ("ground", "ground fallback")):
        st = s["error_map"][which]
        if st["visible_cells"]:
            typer.echo(f"  {name:<16} median {st['median_m']:.3f} m, 90% {st['p90_m']:.3f} m, max {st['max_m']:.3f} m over {st['visible_cells']} visible {s['error_map']['grid_m']:g} m cells")
    for p in s["cross_check"]:
        typer.echo(f"cross-check {p['text']}")
    for k in ("error_map_png", "overlay"):
        if s[k]:
            typer.echo(f"{k.replace('_png', '').replace('_', ' ')}: {s[k]}")

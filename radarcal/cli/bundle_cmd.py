"""``radarcal bundle``: show, validate, import, export, set-transform."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal import geometry
from radarcal.bundle import Provenance, hash_inputs, load_bundle, load_or_create_bundle, save_bundle
from radarcal.cli.common import JsonOpt, command_line, emit, parse_image_size
from radarcal.io.outputs import check_outputs
from radarcal.errors import InputError
from radarcal.io import export_camera, import_camera, read_transform
from radarcal.io.camera_formats import EXPORT_FORMATS
from radarcal.readout import bundle_summary, bundle_summary_lines, entry_readout
from radarcal.readout import format_camera_in_lidar as describe_T_cam_lidar

app = typer.Typer(help="Inspect and edit the calibration bundle.", no_args_is_help=True)


@app.command()
def show(bundle: Path = typer.Argument(..., help="Bundle file."), as_json: JsonOpt = False) -> None:
    """Print what the bundle holds."""
    b = load_bundle(bundle)

    emit(bundle_summary(b), as_json, lambda s: typer.echo("\n".join(bundle_summary_lines(s))))


@app.command()
def validate(bundle: Path = typer.Argument(..., help="Bundle file."), as_json: JsonOpt = False) -> None:
    """Load and check the bundle; exit 0 when valid, 2 with the offending field otherwise."""
    from radarcal.verdicts import forced_entries

    b = load_bundle(bundle)
    flags = forced_entries(b)
    summary = {"ok": True, "path": str(bundle), "cameras": sorted(b.cameras), "transforms": sorted(b.transforms)}
    if flags:
        summary["warnings"] = flags

    def human(s: dict) -> None:
        typer.echo(f"ok: {bundle}: {len(b.cameras)} camera(s), {len(b.transforms)} transform(s)" + (f", {len(flags)} flagged" if flags else ""))
        for w in flags:
            typer.echo(f"  warning: {w}")

    emit(summary, as_json, human)


@app.command("import")
def import_(
    bundle: Path = typer.Argument(..., help="Bundle file (created if missing)."),
    file: Path = typer.Argument(..., help="ROS camera_info YAML, OpenCV YAML, Kalibr camchain, radarcal JSON, KITTI calib_*.txt, OpenCalib intrinsic JSON or Calib-Anything calib.txt."),
    camera: str = typer.Option(..., "--camera", help="Name of the camera in the bundle, e.g. cam0."),
    select: str = typer.Option(None, "--select", help="Camera inside a multi-camera file (Kalibr cam1; OpenCV stereo 'left'/'right' = M1/D1 or M2/D2; KITTI cam0..cam3, default cam2)."),
    image_size: str = typer.Option(None, "--image-size", help="WIDTHxHEIGHT, for files that do not record it (OpenCV stereo_calib output, KITTI)."),
    lidar: str = typer.Option("lidar0", "--lidar", help="Frame name for the LiDAR -> camera extrinsic when the file also holds one (KITTI Tr_velo_to_cam, Calib-Anything T)."),
    as_json: JsonOpt = False,
) -> None:
    """Import camera intrinsics (and the LiDAR -> camera extrinsic, when the file holds one) from another tool's file."""
    from radarcal.io.camera_formats import kitti_camera_index
    from radarcal.io.tool_calib_files import read_tool_calib

    size = parse_image_size(image_size) if image_size else None
    cam, fmt = import_camera(file, select, size)
    T_cam_lidar = None
    if fmt in ("kitti", "opencalib", "calibanything"):
        T_cam_lidar = read_tool_calib(file, kitti_camera_index(select) if fmt == "kitti" else 2).T_cam_lidar
    b = load_or_create_bundle(bundle)
    prov = Provenance(command=command_line(), inputs_sha256=hash_inputs([file]))
    b.set_camera(camera, cam, provenance=prov, extra={"imported_from": fmt})
    if T_cam_lidar is not None:
        b.set_sensor(lidar, type="lidar")
        b.set_transform(camera, lidar, T_cam_lidar, method=f"imported ({fmt})", provenance=prov)
    save_bundle(b, bundle)
    summary = {"camera": camera, "format": fmt, "K": cam.K, "dist": cam.dist, "image_size": list(cam.image_size), "model": cam.model,
               "T_cam_lidar": T_cam_lidar, "transform": f"T_{camera}_{lidar}" if T_cam_lidar is not None else None}

    def human(s: dict) -> None:
        typer.echo(f"imported {camera} from {file} ({fmt}): {cam.model} {cam.width}x{cam.height} fx={cam.fx:.3f} fy={cam.fy:.3f} cx={cam.cx:.3f} cy={cam.cy:.3f} -> {bundle}")
        if T_cam_lidar is not None:
            typer.echo(f"  and {s['transform']} (LiDAR -> camera) from the same file: {describe_T_cam_lidar(T_cam_lidar)}")

    emit(summary, as_json, human)


@app.command()
def export(
    bundle: Path = typer.Argument(..., help="Bundle file."),
    camera: str = typer.Option(..., "--camera"),
    fmt: str = typer.Option("ros", "--format", help=f"One of: {', '.join(EXPORT_FORMATS)}."),
    out: Path = typer.Option(None, "-o", "--output", help="Output file (stdout if omitted)."),
    as_json: JsonOpt = False,
) -> None:
    """Export one camera's intrinsics for another tool (--json: {camera, format, output, text} on stdout)."""
    if fmt not in EXPORT_FORMATS:  # checked here, not by an Enum: a bad value is one line `error: --format: ...`
        raise InputError("--format", f"unknown format {fmt!r} (choose {', '.join(EXPORT_FORMATS)})")
    b = load_bundle(bundle)
    text = export_camera(b.camera(camera), fmt, camera)
    if out is not None:
        check_outputs(bundle, [("export", out)], b)
        try:
            out.write_text(text)
        except OSError as e:
            raise InputError(out, f"cannot write ({e.strerror or e.__class__.__name__})") from None
        typer.echo(f"wrote {out} ({fmt})", err=True)
    if as_json:
        emit({"camera": camera, "format": fmt, "output": None if out is None else str(out), "text": text}, True, lambda s: None)
    elif out is None:
        typer.echo(text, nl=False)


@app.command("set-transform")
def set_transform(
    bundle: Path = typer.Argument(..., help="Bundle file (created if missing)."),
    target: str = typer.Argument(..., help="Target frame a of T_a_b (e.g. cam0)."),
    source: str = typer.Argument(..., help="Source frame b of T_a_b (e.g. lidar0)."),
    file: Path = typer.Argument(..., help="4x4 as JSON or text, or 'x y z roll pitch yaw' (m, deg)."),
    as_json: JsonOpt = False,
) -> None:
    """Store T_target_source (maps points in SOURCE into TARGET) from a file."""
    if target == source:
        raise InputError("TARGET/SOURCE", f"a transform needs two different frames, got {target!r} twice")
    T = read_transform(file)
    b = load_or_create_bundle(bundle)
    b.set_transform(target, source, T, method="manual (set-transform)", provenance=Provenance(command=command_line(), inputs_sha256=hash_inputs([file])))
    from radarcal.extrinsics.lidar_camera_chain import refresh_derived

    refresh_derived(b, command_line())  # transforms derived through a stereo pair follow the new entry
    save_bundle(b, bundle)
    xyz_rpy = geometry.T_to_xyz_rpy_deg(T)
    summary = {"name": f"T_{target}_{source}", "target": target, "source": source, "T": T, "xyz_m": xyz_rpy[:3], "rpy_deg": xyz_rpy[3:], "bundle": str(bundle)}
    summary["readout"] = entry_readout(b, b.transforms[f"T_{target}_{source}"])

    def human(s: dict) -> None:
        typer.echo(f"set T_{target}_{source}: xyz=({xyz_rpy[0]:.4f}, {xyz_rpy[1]:.4f}, {xyz_rpy[2]:.4f}) m rpy=({xyz_rpy[3]:.3f}, {xyz_rpy[4]:.3f}, {xyz_rpy[5]:.3f}) deg -> {bundle}")
        if s["readout"]:
            typer.echo(f"  {s['readout']}")

    emit(summary, as_json, human)

"""``radarcal lidar-field``: register an accumulated LiDAR cloud to the field mesh -> ``T_field_<lidar>``."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import BundleOpt, CloudTopicOpt, JsonOpt, command_line, emit, err_console
from radarcal.extrinsics.lidar_field_session import resolve_field_pose

__all__ = ["lidar_field", "resolve_field_pose"]


def lidar_field(
    bundle: BundleOpt = ...,
    lidar: str = typer.Option("lidar0", "--lidar", help="LiDAR frame name in the bundle."),
    cloud: list[Path] = typer.Option(..., "--cloud", help="Accumulated cloud(s) in the LiDAR frame: PCD/PLY/bin/npy, or a ROS1/ROS2 bag (its clouds merged); repeat to add more."),
    cloud_topic: CloudTopicOpt = None,
    field: str = typer.Option(None, "--field", help="Field: built-in name, a field YAML (polygons or `mesh:`) or a mesh file [default: the bundle's field]."),
    field_mesh: Path = typer.Option(None, "--field-mesh", help="Field mesh file (STL/PLY/OBJ) to register to (sidecar <mesh>.yaml read if present)."),
    field_units: str = typer.Option("auto", "--field-units", help="Units of the mesh file: auto (from the extent), mm, cm or m."),
    init: Path = typer.Option(None, "--init", help="Start pose T_field_lidar: JSON {\"T_field_lidar\": 4x4}, 16 numbers, or `x y z roll pitch yaw` (m, deg)."),
    side: str = typer.Option(None, "--side", help="red|blue: global search for a station behind that end (when no --init and no chain)."),
    max_points: int = typer.Option(12_000, "--max-points", help="Points per Gauss-Newton iteration (a random subset of the cloud)."),
    force: bool = typer.Option(False, "--force", help="Store the result even when the verdict is not 'converged'."),
    as_json: JsonOpt = False,
) -> None:
    """Register the LiDAR to the field mesh: robust coarse-to-fine point-to-plane, restarts, σ, degeneracy and a
    verdict; cross-checked against field-pnp when the bundle has T_cam_field and T_cam_lidar."""
    from radarcal.bundle import Provenance, hash_inputs, load_or_create_bundle, save_bundle
    from radarcal.extrinsics.lidar_field_session import calibrate, store

    b = load_or_create_bundle(bundle)  # every input is checked before the long work: the bundle, the field, --init, the clouds
    cal = calibrate(b, bundle, lidar, list(cloud), cloud_topic=cloud_topic, field=field, field_mesh=field_mesh, field_units=field_units, init=init, side=side,
                    max_points=max_points, log=lambda text: err_console.print(text, style="yellow" if text.startswith("warning") else "dim"))  # fmt: skip
    res = cal.result
    stored = res.verdict == "converged" or force
    if stored:
        extra = {"field": cal.field_model.to_dict(), "side": side, "max_points": max_points, "cloud_topic": cloud_topic}
        store(b, cal, Provenance(command=command_line(), inputs_sha256=hash_inputs(list(cloud) + ([init] if init else []), extra=extra)))
        save_bundle(b, bundle)
    summary = {**cal.summary(), "stored": stored, "bundle": str(bundle)}

    def human(s: dict) -> None:
        x, sg = s["xyz_rpy_deg"], res.sigma
        typer.echo(f"lidar-field {lidar} on {s['field']}: {res.verdict}{' — ' + '; '.join(res.reasons) if res.reasons else ''}")
        typer.echo(f"  start: {cal.start}; {res.n_points} points, {res.inliers} within {cal.options.gates_m[-1] * 100:.0f} cm, {res.inlier_share:.0%} of those near the mesh "
                   f"within {cal.options.inlier_m * 100:.0f} cm; residual {res.rms_m * 100:.2f} cm RMS; {res.seconds:.1f} s")  # fmt: skip
        typer.echo(f"  T_field_{lidar}: x={x[0]:.3f} y={x[1]:.3f} z={x[2]:.3f} m  roll={x[3]:.3f} pitch={x[4]:.3f} yaw={x[5]:.3f} deg")
        typer.echo(f"  1σ: x {sg['x'] * 100:.2f} y {sg['y'] * 100:.2f} z {sg['z'] * 100:.2f} cm, roll {sg['roll']:.4f} pitch {sg['pitch']:.4f} yaw {sg['yaw']:.4f} deg")
        if res.weak_directions:
            typer.echo(f"  weakly observed: {', '.join(res.weak_directions)}")
        for c in s["cross_check"]:
            typer.echo(f"  cross-check {c['camera']}: chain vs field-pnp differ by {c['deg']:.3f} deg, {c['cm']:.1f} cm -> {c['ground_error_m']['10m']:.3f} m at 10 m, "
                       f"{c['ground_error_m']['20m']:.3f} m at 20 m{'  WARNING: beyond 3σ' if c['warning'] else ''}")  # fmt: skip
        typer.echo(f"wrote T_field_{lidar} to {bundle}" if stored else f"not stored (verdict {res.verdict}); pass --force to store it anyway")

    emit(summary, as_json, human)
    if not stored:
        raise typer.Exit(1)

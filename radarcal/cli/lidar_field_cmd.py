"""``radarcal lidar-field``: register an accumulated LiDAR cloud to the field mesh -> ``T_field_<lidar>``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from radarcal.bundle import Provenance, hash_inputs, load_or_create_bundle, save_bundle
from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console
from radarcal.errors import InputError


def _direct(b, target: str, source: str) -> tuple[np.ndarray, dict] | None:
    """A transform stored directly between two frames (either direction) and its σ, or None."""
    from radarcal import geometry

    e = b.transforms.get(f"T_{target}_{source}")
    if e is not None:
        return np.asarray(e.T, float), dict(e.sigma)
    e = b.transforms.get(f"T_{source}_{target}")
    if e is not None:
        return geometry.invert_T(np.asarray(e.T, float)), dict(e.sigma)
    return None


def _start_pose(b, lidar: str, init: Path | None, side: str | None, cloud: np.ndarray, target, fm) -> tuple[list[np.ndarray], str]:
    from radarcal import geometry
    from radarcal.extrinsics.lidar_field import side_search
    from radarcal.io.matrices import read_transform

    if init is not None:
        return [read_transform(init)], f"--init {init}"
    cams = [c for c in b.cameras if _direct(b, "field", c) is not None and _direct(b, c, lidar) is not None]
    if cams:
        c = cams[0]
        T = _direct(b, "field", c)[0] @ _direct(b, c, lidar)[0]
        return [T], f"the bundle's chain T_field_{c} · T_{c}_{lidar}"
    if b.has_T("field", lidar):
        return [b.T("field", lidar)], f"the bundle's T_field_{lidar}"
    if side is None:
        raise InputError("--side", "no start pose: pass --init FILE, or --side red|blue for a global search, or store T_field_cam (field-pnp) and T_cam_lidar (lidar-camera) in the bundle")
    err_console.print(f"global search behind the {side} end (floor plane, then x / y / yaw) ...", style="dim")
    starts = side_search(cloud, target, fm.size, side)
    if not starts:
        raise InputError("--side", "the global search found no start pose (no floor plane below the sensor?)")
    del geometry
    return starts, f"global search behind the {side} end ({len(starts)} candidates)"


def lidar_field(
    bundle: BundleOpt = ...,
    lidar: str = typer.Option("lidar0", "--lidar", help="LiDAR frame name in the bundle."),
    cloud: list[Path] = typer.Option(..., "--cloud", help="Accumulated cloud(s) in the LiDAR frame (PCD/PLY/bin/npy); repeat to add more."),
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
    from radarcal import geometry
    from radarcal.extrinsics.lidar_field import LidarFieldOptions, MeshTarget, register_lidar_field
    from radarcal.field import FieldModel, load_field, polygon_field_mesh
    from radarcal.io import read_cloud

    if side is not None and side not in ("red", "blue"):
        raise InputError("--side", f"expected red or blue, got {side!r}")
    if field is not None and field_mesh is not None:
        raise InputError("--field-mesh", "give either --field or --field-mesh, not both")
    if max_points < 1000:
        raise InputError("--max-points", f"at least 1000, got {max_points}")
    b = load_or_create_bundle(bundle)  # every input is checked before the long work: the bundle, the field, --init, the clouds
    if field_mesh is not None:
        fm = load_field(field_mesh, units=field_units)
        field_src = str(field_mesh)
    elif field is not None:
        fm = load_field(field, units=field_units)
        field_src = field
    elif b.field_model:
        fm = FieldModel.from_dict(b.field_model, f"{bundle}: field")
        field_src = f"{bundle} (field_model)"
    else:
        raise InputError("--field-mesh", "no field: pass --field-mesh MESH.stl (or --field) — the bundle holds no field model")
    mesh = fm.mesh if fm.mesh is not None else polygon_field_mesh(fm)
    if init is not None:
        from radarcal.io.matrices import read_transform

        read_transform(init)
    pts = []
    for c in cloud:
        cl = read_cloud(c)
        if len(cl) == 0:
            raise InputError(c, "empty point cloud")
        pts.append(np.asarray(cl.points, float))
    P = np.concatenate(pts)
    P = P[np.all(np.isfinite(P), axis=1) & (np.linalg.norm(P, axis=1) > 0.1)]
    if len(P) < 1000:
        raise InputError(cloud[0], f"only {len(P)} usable points (need >= 1000 for a registration)")
    if fm.mesh is None:
        err_console.print(f"warning: {fm.name} is a polygon field, not a mesh; registering to its triangulation", style="yellow")
    target = MeshTarget(mesh)
    starts, start_src = _start_pose(b, lidar, init, side, P, target, fm)
    opt = LidarFieldOptions(max_points=max_points)
    res = register_lidar_field(P, target, starts, opt)
    if res.verdict == "failed":
        raise InputError(cloud[0], "registration failed — " + "; ".join(res.reasons) + " (a cloud of this field? the right --side / --init?)")

    # --- cross-check against field-pnp ---------------------------------------------------------------------
    checks = []
    for cam in b.cameras:
        pnp = _direct(b, cam, "field")
        cl = _direct(b, cam, lidar)
        if pnp is None or cl is None:
            continue
        T_field_cam_chain = res.T_field_lidar @ geometry.invert_T(cl[0])
        T_field_cam_pnp = geometry.invert_T(pnp[0])
        deg, m = geometry.pose_error(T_field_cam_chain, T_field_cam_pnp)
        C = T_field_cam_pnp[:3, 3]
        fwd = T_field_cam_pnp[:3, 2].copy()
        fwd[2] = 0
        fwd /= max(np.linalg.norm(fwd), 1e-9)
        at = {}
        for r in (10.0, 20.0):
            p = np.array([C[0], C[1], 0.0]) + r * fwd
            q = T_field_cam_chain @ geometry.invert_T(T_field_cam_pnp) @ np.append(p, 1.0)
            at[f"{r:g}m"] = float(np.linalg.norm(q[:2] - p[:2]))
        sp = pnp[1]
        s_rot = float(np.linalg.norm(sp.get("rot_deg", [0, 0, 0]))) if sp.get("rot_deg") is not None else 0.0
        s_pos = float(np.linalg.norm(sp.get("camera_position_m", [0, 0, 0]))) if sp.get("camera_position_m") is not None else 0.0
        s_rot = float(np.hypot(s_rot, np.linalg.norm([res.sigma["roll"], res.sigma["pitch"], res.sigma["yaw"]])))
        s_pos = float(np.hypot(s_pos, np.linalg.norm([res.sigma["x"], res.sigma["y"], res.sigma["z"]])))
        warn = (s_rot > 0 and deg > 3 * s_rot) or (s_pos > 0 and m > 3 * s_pos)
        checks.append({"camera": cam, "deg": deg, "cm": 100 * m, "ground_error_m": at, "sigma_deg": s_rot, "sigma_cm": 100 * s_pos, "warning": bool(warn)})

    stored = res.verdict == "converged" or force
    if stored:
        prov = Provenance(command=command_line(), inputs_sha256=hash_inputs(list(cloud) + ([init] if init else []), extra={"field": fm.to_dict(), "side": side, "max_points": max_points}))
        b.set_sensor(lidar, type="lidar")
        b.set_transform("field", lidar, res.T_field_lidar, method=f"lidar-field: robust point-to-plane to {fm.name} ({fm.backing}), start {start_src}; verdict {res.verdict}",
                        residual={"rms_m": res.rms_m, "inliers": res.inliers, "inlier_share": res.inlier_share, "n_points": res.n_points, "verdict": res.verdict, "reasons": res.reasons},
                        sigma={"x_m": res.sigma["x"], "y_m": res.sigma["y"], "z_m": res.sigma["z"], "roll_deg": res.sigma["roll"], "pitch_deg": res.sigma["pitch"], "yaw_deg": res.sigma["yaw"]},
                        provenance=prov)
        if field is not None or field_mesh is not None or not b.field_model:
            b.field_model = fm.to_dict()
        save_bundle(b, bundle)
    summary = {"lidar": lidar, "field": fm.name, "field_source": field_src, "start": start_src, **res.summary(), "T_field_lidar": res.T_field_lidar,
               "cross_check": checks, "stored": stored, "bundle": str(bundle)}

    def human(s: dict) -> None:
        x = s["xyz_rpy_deg"]
        sg = res.sigma
        typer.echo(f"lidar-field {lidar} on {fm.name}: {res.verdict}{' — ' + '; '.join(res.reasons) if res.reasons else ''}")
        typer.echo(f"  start: {start_src}; {res.n_points} points, {res.inliers} within {opt.gates_m[-1] * 100:.0f} cm, {res.inlier_share:.0%} of those near the mesh within {opt.inlier_m * 100:.0f} cm; residual {res.rms_m * 100:.2f} cm RMS; {res.seconds:.1f} s")
        typer.echo(f"  T_field_{lidar}: x={x[0]:.3f} y={x[1]:.3f} z={x[2]:.3f} m  roll={x[3]:.3f} pitch={x[4]:.3f} yaw={x[5]:.3f} deg")
        typer.echo(f"  1σ: x {sg['x'] * 100:.2f} y {sg['y'] * 100:.2f} z {sg['z'] * 100:.2f} cm, roll {sg['roll']:.4f} pitch {sg['pitch']:.4f} yaw {sg['yaw']:.4f} deg")
        if res.weak_directions:
            typer.echo(f"  weakly observed: {', '.join(res.weak_directions)}")
        for c in checks:
            flag = "  WARNING: beyond 3σ" if c["warning"] else ""
            typer.echo(f"  cross-check {c['camera']}: chain vs field-pnp differ by {c['deg']:.3f} deg, {c['cm']:.1f} cm -> {c['ground_error_m']['10m']:.3f} m at 10 m, {c['ground_error_m']['20m']:.3f} m at 20 m{flag}")
        typer.echo(f"wrote T_field_{lidar} to {bundle}" if stored else f"not stored (verdict {res.verdict}); pass --force to store it anyway")

    emit(summary, as_json, human)
    if not stored:
        raise typer.Exit(1)


def resolve_field_pose(b, camera: str, lidar: str | None, mode: str = "auto") -> tuple[np.ndarray | None, str]:
    """The camera's field pose for ``radarcal run --field-pose``: ``pnp`` (the stored T_cam_field), ``chain``
    (T_field_lidar from lidar-field · T_lidar_cam), ``auto`` (the chain when lidar-field converged, else pnp).
    Returns (T_field_cam or None to leave the bundle's own path, a description)."""
    from radarcal import geometry

    if mode not in ("auto", "chain", "pnp"):
        raise InputError("--field-pose", f"expected auto, chain or pnp, got {mode!r}")
    pnp = _direct(b, camera, "field")
    chain = None
    if lidar is not None:
        fl = b.transforms.get(f"T_field_{lidar}")
        cl = _direct(b, camera, lidar)
        if fl is not None and cl is not None:
            chain = (np.asarray(fl.T, float) @ geometry.invert_T(cl[0]), fl.residual.get("verdict", ""))
    if mode == "pnp":
        if pnp is None:
            raise InputError("--field-pose", f"pnp: no T_{camera}_field (field-pnp) in the bundle")
        return geometry.invert_T(pnp[0]), f"field-pnp T_{camera}_field"
    if mode == "chain":
        if chain is None:
            raise InputError("--field-pose", f"chain: needs T_field_{lidar} (lidar-field) and T_{camera}_{lidar} in the bundle")
        return chain[0], f"chain T_field_{lidar} · T_{lidar}_{camera}"
    if chain is not None and (chain[1] == "converged" or pnp is None):
        return chain[0], f"chain T_field_{lidar} · T_{lidar}_{camera} (auto)"
    return (geometry.invert_T(pnp[0]), f"field-pnp T_{camera}_field (auto)") if pnp is not None else (None, "the bundle's transform chain")

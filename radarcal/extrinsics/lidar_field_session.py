"""``radarcal lidar-field`` orchestration: inputs (field, start pose, clouds or bags) -> registration -> cross-check
against field-pnp -> the bundle entry. :func:`calibrate` returns a :class:`LidarFieldCalibration` (no printing);
:func:`store` writes it; :func:`resolve_field_pose` is the camera's field pose ``radarcal run --field-pose`` uses.

Frames: clouds in the LiDAR frame, ``T_field_lidar`` maps them into the field frame; metres and radians inside."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError
from radarcal.extrinsics.lidar_field import LidarFieldOptions, LidarFieldResult, MeshTarget, register_lidar_field, side_search

__all__ = ["LidarFieldCalibration", "calibrate", "store", "resolve_field_pose", "load_target_field", "read_clouds", "cross_check"]


@dataclass
class LidarFieldCalibration:
    lidar: str
    result: LidarFieldResult
    field_model: object                   # radarcal.field.FieldModel registered to
    field_source: str
    start: str                            # where the start pose came from
    options: LidarFieldOptions
    cross_checks: list[dict] = field(default_factory=list)
    field_given: bool = False             # the field came from --field / --field-mesh (the bundle's field is replaced)

    def summary(self) -> dict:
        return {"lidar": self.lidar, "field": self.field_model.name, "field_source": self.field_source, "start": self.start, **self.result.summary(),
                "T_field_lidar": self.result.T_field_lidar, "cross_check": self.cross_checks}  # fmt: skip


def _direct(b, target: str, source: str) -> tuple[np.ndarray, dict] | None:
    """A transform stored directly between two frames (either direction) and its σ, or None."""
    e = b.transforms.get(f"T_{target}_{source}")
    if e is not None:
        return np.asarray(e.T, float), dict(e.sigma)
    e = b.transforms.get(f"T_{source}_{target}")
    if e is not None:
        return geometry.invert_T(np.asarray(e.T, float)), dict(e.sigma)
    return None


def load_target_field(b, bundle_path, field: str | None, field_mesh: os.PathLike | None, units: str = "auto"):
    """(FieldModel, description, given by the user?) from --field-mesh, --field or the bundle's field."""
    from radarcal.field import FieldModel, load_field

    if field is not None and field_mesh is not None:
        raise InputError("--field-mesh", "give either --field or --field-mesh, not both")
    if field_mesh is not None:
        return load_field(field_mesh, units=units), str(field_mesh), True
    if field is not None:
        return load_field(field, units=units), field, True
    if b.field_model:
        return FieldModel.from_dict(b.field_model, f"{bundle_path}: field"), f"{bundle_path} (field_model)", False
    raise InputError("--field-mesh", "no field: pass --field-mesh MESH.stl (or --field) — the bundle holds no field model")


def read_clouds(paths: list, topic: str | None = None) -> np.ndarray:
    """The accumulated cloud (N,3) of every ``--cloud``: cloud files as they are, bags (ROS1/ROS2) merged over
    ``topic`` (:func:`radarcal.io.cloud_sources.read_scene_cloud`); non-finite and < 0.1 m points dropped."""
    from radarcal.io.cloud_sources import read_scene_cloud

    pts = []
    for c in paths:
        cl = read_scene_cloud(c, topic)
        if len(cl) == 0:
            raise InputError(c, "empty point cloud")
        pts.append(np.asarray(cl.points, float))
    P = np.concatenate(pts)
    P = P[np.all(np.isfinite(P), axis=1) & (np.linalg.norm(P, axis=1) > 0.1)]
    if len(P) < 1000:
        raise InputError(paths[0], f"only {len(P)} usable points (need >= 1000 for a registration)")
    return P


def _start_poses(b, lidar: str, init, side: str | None, cloud: np.ndarray, target: MeshTarget, fm, log=None) -> tuple[list[np.ndarray], str]:
    """--init; else the bundle's chain T_field_cam · T_cam_lidar; else its T_field_lidar; else a search from --side."""
    from radarcal.io.matrices import read_transform

    if init is not None:
        return [read_transform(init)], f"--init {init}"
    cams = [c for c in b.cameras if _direct(b, "field", c) is not None and _direct(b, c, lidar) is not None]
    if cams:
        c = cams[0]
        return [_direct(b, "field", c)[0] @ _direct(b, c, lidar)[0]], f"the bundle's chain T_field_{c} · T_{c}_{lidar}"
    if b.has_T("field", lidar):
        return [b.T("field", lidar)], f"the bundle's T_field_{lidar}"
    if side is None:
        raise InputError("--side", "no start pose: pass --init FILE, or --side red|blue for a global search, or store T_field_cam (field-pnp) and T_cam_lidar (lidar-camera) in the bundle")
    if log is not None:
        log(f"global search behind the {side} end (floor plane, then x / y / yaw) ...")
    starts = side_search(cloud, target, fm.size, side)
    if not starts:
        raise InputError("--side", "the global search found no start pose (no floor plane below the sensor?)")
    return starts, f"global search behind the {side} end ({len(starts)} candidates)"


def cross_check(b, lidar: str, res: LidarFieldResult) -> list[dict]:
    """Per camera with both T_cam_field (field-pnp) and T_cam_lidar: how far the chain's camera field pose is from
    field-pnp's (deg, cm, ground error at 10 m and 20 m ahead), warning beyond 3σ."""
    checks = []
    for cam in b.cameras:
        pnp, cl = _direct(b, cam, "field"), _direct(b, cam, lidar)
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
    return checks


def calibrate(b, bundle_path, lidar: str, clouds: list, *, cloud_topic: str | None = None, field: str | None = None, field_mesh=None,
              field_units: str = "auto", init=None, side: str | None = None, max_points: int = 12_000, log=None) -> LidarFieldCalibration:  # fmt: skip
    """Register the accumulated cloud(s) to the field: every input is checked before the long work (field, --init,
    the clouds); a failed registration raises :class:`InputError` naming the first cloud. ``log(text)``: progress."""
    from radarcal.field import polygon_field_mesh
    from radarcal.io.matrices import read_transform

    if side is not None and side not in ("red", "blue"):
        raise InputError("--side", f"expected red or blue, got {side!r}")
    if max_points < 1000:
        raise InputError("--max-points", f"at least 1000, got {max_points}")
    fm, field_src, given = load_target_field(b, bundle_path, field, field_mesh, field_units)
    if init is not None:
        read_transform(init)
    P = read_clouds(list(clouds), cloud_topic)
    if fm.mesh is None and log is not None:
        log(f"warning: {fm.name} is a polygon field, not a mesh; registering to its triangulation")
    target = MeshTarget(fm.mesh if fm.mesh is not None else polygon_field_mesh(fm))
    starts, start_src = _start_poses(b, lidar, init, side, P, target, fm, log)
    opt = LidarFieldOptions(max_points=max_points)
    res = register_lidar_field(P, target, starts, opt)
    if res.verdict == "failed":
        raise InputError(clouds[0], "registration failed — " + "; ".join(res.reasons) + " (a cloud of this field? the right --side / --init?)")
    return LidarFieldCalibration(lidar, res, fm, field_src, start_src, opt, cross_check(b, lidar, res), given)


def store(b, cal: LidarFieldCalibration, provenance) -> None:
    """Write ``T_field_<lidar>`` (method, residual, σ, provenance) into the bundle ``b`` (in memory), and the field
    registered to when it was given or the bundle had none."""
    res = cal.result
    b.set_sensor(cal.lidar, type="lidar")
    b.set_transform("field", cal.lidar, res.T_field_lidar, method=f"lidar-field: robust point-to-plane to {cal.field_model.name} ({cal.field_model.backing}), start {cal.start}; verdict {res.verdict}",
                    residual={"rms_m": res.rms_m, "inliers": res.inliers, "inlier_share": res.inlier_share, "n_points": res.n_points, "verdict": res.verdict, "reasons": res.reasons},
                    sigma={"x_m": res.sigma["x"], "y_m": res.sigma["y"], "z_m": res.sigma["z"], "roll_deg": res.sigma["roll"], "pitch_deg": res.sigma["pitch"], "yaw_deg": res.sigma["yaw"]},
                    provenance=provenance)  # fmt: skip
    if cal.field_given or not b.field_model:
        b.field_model = cal.field_model.to_dict()


def resolve_field_pose(b, camera: str, lidar: str | None, mode: str = "auto") -> tuple[np.ndarray | None, str]:
    """The camera's field pose for ``radarcal run --field-pose``: ``pnp`` (the stored T_cam_field), ``chain``
    (T_field_lidar from lidar-field · T_lidar_cam), ``auto`` (the chain when lidar-field converged, else pnp).
    Returns (T_field_cam or None to leave the bundle's own path, a description)."""
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



"""Poses as people read them. Roll-pitch-yaw of ``T_cam_lidar`` sits at gimbal lock for every level LiDAR (the
camera's z is the LiDAR's x), so a camera's pose is given in a *viewing frame* instead: x along the optical axis,
y to the image's left, z to the image's top (the LiDAR / field convention). A camera looking straight down the
LiDAR's x axis, image upright, then reads yaw = pitch = roll = 0.

- :func:`camera_in_lidar`: where the camera sits in the LiDAR frame and which way it looks (from ``T_cam_lidar``).
- :func:`camera_on_field`: the camera's position on the field and its heading / depression (from ``T_cam_field``).
- :func:`pose_change`: how far one estimate moved from another, as one angle and one distance.
"""

from __future__ import annotations

import numpy as np

from radarcal import geometry

__all__ = ["R_CAM_VIEW", "camera_in_lidar", "camera_on_field", "pose_change", "format_camera_in_lidar", "format_camera_on_field", "bundle_summary", "entry_readout"]

# columns: the viewing frame's axes (forward, left, up) in camera coordinates (x right, y down, z forward)
R_CAM_VIEW = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _view_angles(R_frame_cam: np.ndarray) -> dict[str, float]:
    """yaw (left +), pitch (down +, i.e. looking below the frame's horizon) and roll (about the optical axis, the
    image's left side up +) of the camera's viewing frame in a frame with z up, degrees."""
    R = np.asarray(R_frame_cam, float) @ R_CAM_VIEW
    roll, pitch, yaw = geometry.R_to_rpy_deg(R)
    return {"yaw_deg": float(yaw), "pitch_down_deg": float(pitch), "roll_deg": float(roll)}


def camera_in_lidar(T_cam_lidar: np.ndarray) -> dict:
    """The camera in the LiDAR frame: ``position_m`` (x forward, y left, z up) and its viewing angles relative to the
    LiDAR's forward axis (see the module docstring)."""
    T_lidar_cam = geometry.invert_T(T_cam_lidar)
    return {"position_m": T_lidar_cam[:3, 3].copy(), **_view_angles(T_lidar_cam[:3, :3])}


def camera_on_field(T_cam_field: np.ndarray) -> dict:
    """The camera on the field: ``position_m`` in field coordinates, ``heading_deg`` of its optical axis from the
    field's +x towards +y, ``depression_deg`` below the horizontal, ``roll_deg``."""
    T_field_cam = geometry.invert_T(T_cam_field)
    a = _view_angles(T_field_cam[:3, :3])
    return {"position_m": T_field_cam[:3, 3].copy(), "heading_deg": a["yaw_deg"], "depression_deg": a["pitch_down_deg"], "roll_deg": a["roll_deg"]}


def pose_change(T_from: np.ndarray, T_to: np.ndarray) -> tuple[float, float]:
    """(rotation in degrees, translation in metres) between two estimates of the same transform."""
    return geometry.pose_error(T_to, T_from)


def format_camera_in_lidar(T_cam_lidar: np.ndarray) -> str:
    c = camera_in_lidar(T_cam_lidar)
    x, y, z = c["position_m"]
    return (f"camera at ({x:.3f}, {y:.3f}, {z:.3f}) m in the LiDAR frame (x fwd, y left, z up), looking yaw {c['yaw_deg']:+.3f} deg "
            f"(left +), pitch {c['pitch_down_deg']:+.3f} deg (down +), roll {c['roll_deg']:+.3f} deg from the LiDAR's x axis")


def format_camera_on_field(T_cam_field: np.ndarray) -> str:
    c = camera_on_field(T_cam_field)
    x, y, z = c["position_m"]
    return (f"camera at ({x:.3f}, {y:.3f}, {z:.3f}) m on the field, heading {c['heading_deg']:.2f} deg from +x, "
            f"{c['depression_deg']:.2f} deg below horizontal, roll {c['roll_deg']:+.2f} deg")


def bundle_summary(b) -> dict:
    """What ``radarcal bundle show`` prints: cameras, transforms (with xyz / rpy and the camera readout), sensors, field, runtime, sessions,
    the cameras' cross-checks."""
    cams = {
        n: {"model": e.camera.model, "image_size": list(e.camera.image_size), "K": e.camera.K, "dist": e.camera.dist, "rms_px": e.rms_px, "sigma": e.sigma, "provenance": e.provenance.to_dict()}
        for n, e in b.cameras.items()
    }
    tfs = {}
    for n, e in b.transforms.items():
        xyz_rpy = geometry.T_to_xyz_rpy_deg(e.T)
        tfs[n] = {"target": e.target, "source": e.source, "T": e.T, "xyz_m": xyz_rpy[:3], "rpy_deg": xyz_rpy[3:], "method": e.method, "residual": e.residual, "sigma": e.sigma,
                  "readout": entry_readout(b, e)}
    from radarcal.pnp.cross_check import bundle_cross_checks, format_agreement

    checks = [{**vars(p), "text": format_agreement(p)} for p in bundle_cross_checks(b)]  # how well the cameras agree on the same field point
    return {"path": str(b.path), "cameras": cams, "sensors": b.sensors, "transforms": tfs, "field": (b.field_model or {}).get("name"), "runtime": b.runtime, "sessions": b.sessions,
            "cross_check": checks}


def entry_readout(b, e) -> str | None:
    """The camera's pose as people read it (see radarcal.readout) when the entry relates a camera to a LiDAR or the
    field; None otherwise."""
    cam, other = (e.target, e.source) if e.target in b.cameras else (e.source, e.target) if e.source in b.cameras else (None, None)
    if cam is None or other in b.cameras:
        return None
    T_cam_other = b.T(cam, other)
    return format_camera_on_field(T_cam_other) if other == "field" else format_camera_in_lidar(T_cam_other)


def bundle_summary_lines(s: dict) -> list[str]:
    """The human lines of ``radarcal bundle show`` for a :func:`bundle_summary` dict."""
    out = []
    out.append(f"bundle {s['path']}")
    for n, c in s["cameras"].items():
        K = c["K"]
        rms = "-" if c["rms_px"] is None else f"{c['rms_px']:.3f} px"
        out.append(f"  camera {n}: {c['model']} {c['image_size'][0]}x{c['image_size'][1]}  fx={K[0][0]:.2f} fy={K[1][1]:.2f} cx={K[0][2]:.2f} cy={K[1][2]:.2f}  dist={np.array2string(np.asarray(c['dist']), precision=5)}  rms={rms}")
    for n, t in s["transforms"].items():
        x, y, z = t["xyz_m"]
        r, p, yw = t["rpy_deg"]
        out.append(f"  {n}: xyz=({x:.4f}, {y:.4f}, {z:.4f}) m  rpy=({r:.3f}, {p:.3f}, {yw:.3f}) deg  [{t['method'] or '-'}]")
        if t["readout"]:
            out.append(f"      {t['readout']}")
    for n, meta in s["sensors"].items():
        if meta.get("type") != "camera":
            out.append(f"  sensor {n}: {meta}")
    if s["field"]:
        out.append(f"  field: {s['field']}")
    out.append(f"  runtime: {s['runtime']}")
    for c in s["cross_check"]:
        out.append(f"  cross-check {c['text']}")
    return out

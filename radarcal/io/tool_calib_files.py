"""Calibration files of other LiDAR-camera tools that hold intrinsics and/or a LiDAR -> camera extrinsic.

- **KITTI** ``calib_*.txt`` (object benchmark / raw ``calib_velo_to_cam`` style lines ``KEY: numbers``): ``P0..P3``
  (3x4 rectified projections), ``R0_rect`` (3x3), ``Tr_velo_to_cam`` (3x4). Camera ``k`` (default 2, the left colour
  camera) becomes ``K = P_k[:, :3]``, no distortion (the images are rectified), and
  ``T_camk_lidar = [I | K^-1 P_k[:, 3]] @ R0_rect @ Tr_velo_to_cam`` (the ``[I | t]`` factor is the rectified
  cam0 -> camk offset), so that ``u ~ K @ T_camk_lidar @ p_lidar`` is KITTI's ``P_k @ R0_rect @ Tr_velo_to_cam``.
  KITTI files do not record the image size: it is given by the caller.
- **OpenCalib** (``PJLab-ADG/SensorsCalibration``) JSON: ``{"<sensor>-intrinsic": {"param": {"img_dist_w",
  "img_dist_h", "cam_K": {"data"}, "cam_dist": {"data"}}}}`` and ``{"<a>-to-<b>-extrinsic": {"sensor_name": a,
  "target_sensor_name": b, "param": {"sensor_calib": {"data": 4x4}}}}`` with ``p_b = T @ p_a`` (LiDAR -> camera).
- **Calib-Anything** ``calib.txt`` (OpenCalib v2.0): lines ``K:`` (9 numbers row-major), ``D:`` (k1 k2 p1 p2 [k3]),
  ``T:`` (12 numbers, the 3x4 LiDAR -> camera).

All return a :class:`ToolCalib`; frames: ``T_cam_lidar`` maps LiDAR points into the camera (``p_cam = T @ p_lidar``).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError, read_text

__all__ = ["ToolCalib", "detect_tool_format", "read_tool_calib", "TOOL_FORMATS"]

TOOL_FORMATS = ("kitti", "opencalib", "calibanything")
_LINE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)$")


@dataclass
class ToolCalib:
    """What another tool's file holds. ``K``/``dist``/``image_size`` are None when it holds no intrinsics (an
    extrinsic-only OpenCalib file); ``T_cam_lidar`` None when it holds no extrinsic."""

    format: str
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    T_cam_lidar: np.ndarray | None = None
    camera_name: str = ""  # the tool's own name of the camera (OpenCalib sensor name, KITTI ``cam2``)
    lidar_name: str = ""
    note: str = ""


def _key_lines(text: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        m = _LINE.match(line)
        if m:
            out[m[1]] = m[2].replace(",", " ").split()
    return out


def detect_tool_format(text: str) -> str | None:
    """``kitti`` | ``opencalib`` | ``calibanything`` | None, from the content."""
    head = text.lstrip()[:8192]
    if head.startswith("{"):
        try:
            d = json.loads(text)
        except ValueError:
            return None
        if isinstance(d, dict) and d and all(isinstance(k, str) and k.endswith(("-intrinsic", "-extrinsic")) for k in d):
            return "opencalib"
        return None
    keys = _key_lines(head)
    if "Tr_velo_to_cam" in keys or any(k in keys for k in ("P0", "P1", "P2", "P3")):
        return "kitti"
    if {"K", "T"} <= set(keys) or {"K", "D"} <= set(keys):
        return "calibanything"
    return None


def _numbers(values: list[str], n: tuple[int, ...], what: str, path: Path) -> np.ndarray:
    try:
        a = np.array([float(v) for v in values])
    except ValueError:
        raise InputError(path, f"{what}: expected numbers") from None
    if a.size not in n:
        raise InputError(path, f"{what}: expected {' or '.join(map(str, n))} numbers, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise InputError(path, f"{what}: non-finite value")
    return a


def _rigid(T: np.ndarray, what: str, path: Path) -> np.ndarray:
    T = np.asarray(T, float).reshape(4, 4) if np.size(T) == 16 else np.vstack([np.asarray(T, float).reshape(3, 4), [0, 0, 0, 1]])
    if not np.allclose(T[3], [0, 0, 0, 1]) or not geometry.is_rotation(T[:3, :3], tol=1e-4):
        raise InputError(path, f"{what}: not a rigid transform (rotation part not orthonormal or last row not 0 0 0 1)")
    # re-orthonormalise the 6-7 significant digits these files carry, so chaining stays exact
    u, _, vt = np.linalg.svd(T[:3, :3])
    T = T.copy()
    T[:3, :3] = u @ vt
    return T


def _read_kitti(path: Path, text: str, camera_index: int) -> ToolCalib:
    keys = _key_lines(text)
    pk = f"P{camera_index}"
    if pk not in keys:
        raise InputError(path, f"KITTI calibration has no {pk} (camera {camera_index}; keys: {', '.join(sorted(keys))})")
    P = _numbers(keys[pk], (12,), pk, path).reshape(3, 4)
    K = P[:, :3].copy()
    if abs(K[2, 2]) < 1e-12 or abs(K[0, 0]) < 1e-9:
        raise InputError(path, f"{pk}: not a camera projection (K[2,2] or fx is zero)")
    K = K / K[2, 2]
    T = None
    if "Tr_velo_to_cam" in keys:
        Tr = _rigid(_numbers(keys["Tr_velo_to_cam"], (12, 16), "Tr_velo_to_cam", path), "Tr_velo_to_cam", path)
        R0 = np.eye(4)
        if "R0_rect" in keys:
            R0[:3, :3] = _numbers(keys["R0_rect"], (9,), "R0_rect", path).reshape(3, 3)
            R0 = _rigid(R0, "R0_rect", path)
        offset = np.eye(4)
        offset[:3, 3] = np.linalg.solve(K, P[:, 3])
        T = offset @ R0 @ Tr
    return ToolCalib("kitti", K, np.zeros(5), None, T, f"cam{camera_index}", "velo",
                     note=f"K = {pk}[:, :3]; T_cam{camera_index}_lidar = [I | K^-1 {pk}[:, 3]] @ R0_rect @ Tr_velo_to_cam; rectified images (no distortion)")


def _matrix(node, what: str, path: Path) -> np.ndarray:
    data = node.get("data") if isinstance(node, dict) else node
    try:
        return np.asarray(data, float)
    except (TypeError, ValueError):
        raise InputError(path, f"{what}: expected a numeric matrix") from None


def _read_opencalib(path: Path, text: str) -> ToolCalib:
    d = json.loads(text)
    out = ToolCalib("opencalib")
    for key, entry in d.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("param"), dict):
            raise InputError(path, f"{key}: expected an object with 'param'")
        param = entry["param"]
        if key.endswith("-intrinsic"):
            if "cam_K" not in param:
                raise InputError(path, f"{key}: no param.cam_K")
            K = _matrix(param["cam_K"], f"{key}.cam_K", path).reshape(-1)
            if K.size != 9:
                raise InputError(path, f"{key}.cam_K: expected 3x3, got {K.size} numbers")
            dist = _matrix(param.get("cam_dist", {"data": [[0, 0, 0, 0, 0]]}), f"{key}.cam_dist", path).ravel()
            out.K, out.dist = K.reshape(3, 3), dist
            w, h = param.get("img_dist_w"), param.get("img_dist_h")
            if isinstance(w, (int, float)) and isinstance(h, (int, float)) and w > 0 and h > 0:
                out.image_size = (int(w), int(h))
            out.camera_name = str(entry.get("sensor_name", key[: -len("-intrinsic")]))
        else:
            if "sensor_calib" not in param:
                raise InputError(path, f"{key}: no param.sensor_calib")
            T = _matrix(param["sensor_calib"], f"{key}.sensor_calib", path)
            if T.size != 16:
                raise InputError(path, f"{key}.sensor_calib: expected 4x4, got {T.size} numbers")
            out.T_cam_lidar = _rigid(T, f"{key}.sensor_calib", path)
            out.lidar_name = str(entry.get("sensor_name", ""))
            out.camera_name = out.camera_name or str(entry.get("target_sensor_name", ""))
    out.note = "OpenCalib JSON: sensor_calib maps sensor_name points into target_sensor_name (p_cam = T @ p_lidar)"
    return out


def _read_calibanything(path: Path, text: str) -> ToolCalib:
    keys = _key_lines(text)
    out = ToolCalib("calibanything", note="Calib-Anything calib.txt: T is the 3x4 LiDAR -> camera (p_cam = T @ p_lidar)")
    if "K" in keys:
        out.K = _numbers(keys["K"], (9,), "K", path).reshape(3, 3)
        out.dist = _numbers(keys.get("D", ["0"] * 5), (4, 5, 8), "D", path)
    if "T" in keys:
        out.T_cam_lidar = _rigid(_numbers(keys["T"], (12, 16), "T", path), "T", path)
    return out


def read_tool_calib(path: str | os.PathLike, camera_index: int = 2, text: str | None = None) -> ToolCalib:
    """Read a KITTI / OpenCalib / Calib-Anything calibration file (see the module docstring)."""
    path = Path(path)
    text = read_text(path, "calibration file") if text is None else text
    fmt = detect_tool_format(text)
    if fmt == "kitti":
        return _read_kitti(path, text, camera_index)
    if fmt == "opencalib":
        return _read_opencalib(path, text)
    if fmt == "calibanything":
        return _read_calibanything(path, text)
    raise InputError(path, "not a KITTI calib_*.txt, OpenCalib JSON or Calib-Anything calib.txt file")

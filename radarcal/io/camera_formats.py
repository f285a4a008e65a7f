"""Camera-intrinsics interop: ROS camera_info YAML, OpenCV FileStorage YAML/XML, Kalibr camchain YAML, and
radarcal JSON ``{image_size, K, dist, model}``. ``import_camera`` detects the format from the content."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import yaml

from radarcal.camera import Camera
from radarcal.errors import InputError, read_text

__all__ = ["import_camera", "export_camera", "detect_camera_format", "EXPORT_FORMATS"]

EXPORT_FORMATS = ("ros", "opencv", "kalibr", "json")

_OPENCV_K_KEYS = ("camera_matrix", "cameraMatrix", "CameraMat", "K", "M1", "M", "intrinsics", "Camera_Matrix")
_OPENCV_D_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "DistCoeffs", "D", "D1", "Distortion_Coefficients")


def detect_camera_format(text: str) -> str:
    head = text.lstrip()[:4096]
    if head.startswith("%YAML:1") or "!!opencv-matrix" in head or head.startswith("<?xml"):
        return "opencv"
    if head.startswith("{"):
        return "json"
    if "camera_matrix" in head and "distortion_model" in head:
        return "ros"
    if "intrinsics" in head and ("camera_model" in head or "distortion_coeffs" in head):
        return "kalibr"
    if "camera_matrix" in head or "CameraMat" in head:
        return "opencv"
    return "unknown"


def _opencv_model(dist_model: str, path: Path) -> str:
    if dist_model in ("plumb_bob", "rational_polynomial", "radtan", "pinhole", ""):
        return "pinhole"
    if dist_model in ("equidistant", "fisheye"):
        return "fisheye"
    raise InputError(path, f"unsupported distortion model {dist_model!r} (plumb_bob, rational_polynomial, equidistant)")


def _camera(path: Path, size, K, dist, model) -> Camera:
    try:
        return Camera(tuple(int(v) for v in size), np.asarray(K, float).reshape(3, 3), np.asarray(dist, float).ravel(), model)
    except (ValueError, TypeError) as e:
        raise InputError(path, str(e)) from None


def _import_opencv(path: Path, text: str, name: str | None, image_size: tuple[int, int] | None = None) -> Camera:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:  # a parse error surfaces as SystemError from the constructor
        cause = e.__cause__ if isinstance(e, SystemError) and e.__cause__ is not None else e
        import re

        m = re.match(r".*\((\d+)\): (.*)", str(getattr(cause, "func", "") or ""))
        detail = f"line {m[1]}: {m[2]}" if m else str(getattr(cause, "err", "") or "parse error")
        raise InputError(path, f"OpenCV FileStorage cannot parse the file ({detail.strip()[:160]})") from None
    try:
        if not fs.isOpened():
            raise InputError(path, "OpenCV FileStorage cannot open the file")

        def mat(keys):
            for k in keys:
                node = fs.getNode(k)
                if not node.empty():
                    m = node.mat()
                    if m is None and node.isSeq():
                        m = np.array([node.at(i).real() for i in range(node.size())])
                    if m is not None:
                        return k, np.asarray(m, float)
            return None, None

        suffix = "2" if name in ("right", "1") else "1"
        k_keys = ("M" + suffix,) + _OPENCV_K_KEYS if name else _OPENCV_K_KEYS
        d_keys = ("D" + suffix,) + _OPENCV_D_KEYS if name else _OPENCV_D_KEYS
        k_name, K = mat(k_keys)
        if K is None:
            raise InputError(path, f"no camera matrix (looked for {', '.join(_OPENCV_K_KEYS)})")
        _, dist = mat(d_keys)
        dist = np.zeros(5) if dist is None else dist.ravel()

        def num(*keys):
            for k in keys:
                node = fs.getNode(k)
                if not node.empty():
                    return node.real() if not node.isSeq() else [node.at(i).real() for i in range(node.size())]
            return None

        w, h = num("image_width", "Camera.width", "width"), num("image_height", "Camera.height", "height")
        if w is None or h is None:
            size = num("image_size", "imageSize", "resolution")
            if isinstance(size, list) and len(size) == 2:
                w, h = size
        if image_size is not None:
            w, h = image_size
        if w is None or h is None:
            raise InputError(path, "no image size in the file (image_width/image_height, Camera.width/height or image_size); give it with --image-size WxH")
        model_node = fs.getNode("distortion_model")
        model = _opencv_model(model_node.string() if not model_node.empty() else "", path)
        if model == "pinhole" and dist.size == 4 and fs.getNode("distortion_model").empty() and "fisheye" in text.lower():
            model = "fisheye"
        return _camera(path, (w, h), K, dist, model)
    finally:
        fs.release()


def _import_ros(path: Path, d: dict) -> Camera:
    try:
        K = d["camera_matrix"]["data"]
        dist = d.get("distortion_coefficients", {}).get("data", [0] * 5)
        size = (d["image_width"], d["image_height"])
    except (KeyError, TypeError) as e:
        raise InputError(path, f"ROS camera_info: missing key {e}") from None
    return _camera(path, size, K, dist, _opencv_model(str(d.get("distortion_model", "plumb_bob")), path))


def _import_kalibr(path: Path, d: dict, name: str | None) -> Camera:
    cams = {k: v for k, v in d.items() if isinstance(v, dict) and "intrinsics" in v}
    if not cams:
        raise InputError(path, "Kalibr camchain: no camera with 'intrinsics'")
    key = name if name in cams else sorted(cams)[0]
    c = cams[key]
    try:
        fu, fv, pu, pv = c["intrinsics"]
        dist_model = c.get("distortion_model", "radtan")
        model = {"radtan": "pinhole", "equidistant": "fisheye"}.get(dist_model)
        if model is None or c.get("camera_model", "pinhole") != "pinhole":
            raise InputError(path, f"Kalibr camchain: unsupported model {c.get('camera_model')}-{dist_model}")
        return _camera(path, c["resolution"], [[fu, 0, pu], [0, fv, pv], [0, 0, 1]], c.get("distortion_coeffs", [0, 0, 0, 0]), model)
    except (KeyError, ValueError, TypeError) as e:
        raise InputError(path, f"Kalibr camchain {key}: bad or missing field ({e})") from None


def import_camera(path: str | os.PathLike, name: str | None = None, image_size: tuple[int, int] | None = None) -> tuple[Camera, str]:
    """Read intrinsics from any supported file; returns (camera, detected format).

    ``name`` selects a camera in multi-camera files (Kalibr ``cam1``; OpenCV stereo ``left``/``right`` picks
    M1/D1 or M2/D2). ``image_size`` (width, height) is used for files that do not record it (OpenCV's
    ``stereo_calib`` output) and overrides the file's value otherwise."""
    path = Path(path)
    cam, fmt = _import_any(path, name, image_size)
    if image_size is not None and tuple(cam.image_size) != tuple(image_size):
        cam = _camera(path, image_size, cam.K, cam.dist, cam.model)
    return cam, fmt


def _import_any(path: Path, name: str | None, image_size: tuple[int, int] | None) -> tuple[Camera, str]:
    text = read_text(path, errors="replace")
    fmt = detect_camera_format(text)
    if fmt == "opencv":
        return _import_opencv(path, text, name, image_size), fmt
    if fmt == "json":
        try:
            d = json.loads(text)
            return _camera(path, d["image_size"], d["K"], d.get("dist", [0] * 5), d.get("model", "pinhole")), fmt
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise InputError(path, f"radarcal JSON camera: bad or missing field ({e})") from None
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError:
        raise InputError(path, "not valid YAML") from None
    if fmt == "ros" and isinstance(d, dict):
        return _import_ros(path, d), fmt
    if fmt == "kalibr" and isinstance(d, dict):
        return _import_kalibr(path, d, name), fmt
    raise InputError(path, "unrecognised camera file (expected ROS camera_info, OpenCV YAML, Kalibr camchain or radarcal JSON)")


def _ros_model(cam: Camera) -> str:
    if cam.model == "fisheye":
        return "equidistant"
    return "rational_polynomial" if cam.dist.size >= 8 else "plumb_bob"


def export_camera(cam: Camera, fmt: str, name: str = "cam0") -> str:
    """Text of ``cam`` in format ``ros`` | ``opencv`` | ``kalibr`` | ``json``."""
    if fmt == "ros":
        P = np.zeros((3, 4))
        P[:, :3] = cam.K
        d = {
            "image_width": cam.width,
            "image_height": cam.height,
            "camera_name": name,
            "camera_matrix": {"rows": 3, "cols": 3, "data": cam.K.ravel().tolist()},
            "distortion_model": _ros_model(cam),
            "distortion_coefficients": {"rows": 1, "cols": int(cam.dist.size), "data": cam.dist.tolist()},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
            "projection_matrix": {"rows": 3, "cols": 4, "data": P.ravel().tolist()},
        }
        return yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=200)
    if fmt == "opencv":
        import cv2
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            p = os.path.join(tmp, "cam.yaml")
            flags = cv2.FILE_STORAGE_WRITE | getattr(cv2, "FILE_STORAGE_FORMAT_YAML_1_0", 0)
            fs = cv2.FileStorage(p, flags)
            fs.write("image_width", cam.width)
            fs.write("image_height", cam.height)
            fs.write("camera_name", name)
            fs.write("distortion_model", _ros_model(cam))
            fs.write("camera_matrix", cam.K)
            fs.write("distortion_coefficients", cam.dist.reshape(1, -1))
            fs.release()
            return Path(p).read_text()
    if fmt == "kalibr":
        if cam.model == "pinhole" and cam.dist.size > 5 or (cam.dist.size == 5 and cam.dist[4] != 0):
            raise InputError(name, "Kalibr radtan has 4 coefficients; this camera uses more (k3 or rational terms)")
        d = {
            name: {
                "camera_model": "pinhole",
                "intrinsics": [cam.fx, cam.fy, cam.cx, cam.cy],
                "distortion_model": "equidistant" if cam.model == "fisheye" else "radtan",
                "distortion_coeffs": cam.dist[:4].tolist(),
                "resolution": list(cam.image_size),
            }
        }
        return yaml.safe_dump(d, sort_keys=False, default_flow_style=None)
    if fmt == "json":
        return json.dumps(cam.to_dict(), indent=2)
    raise InputError(fmt, f"unknown export format (choose {', '.join(EXPORT_FORMATS)})")

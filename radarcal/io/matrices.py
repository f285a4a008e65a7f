"""4x4 transform files: JSON ``{"T_cam_lidar": [[...]]}`` / ``{"T": ...}`` / bare nested list, plain text with
16 numbers, or 6 numbers ``x y z roll pitch yaw`` (metres, degrees)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError, read_text

__all__ = ["read_transform", "parse_transform_text"]


def parse_transform_text(text: str, source: object = "") -> np.ndarray:
    text = text.strip()
    value = None
    if text.startswith("{") or text.startswith("["):
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            raise InputError(source, "not valid JSON") from None
        if isinstance(value, dict):
            keys = [k for k in value if k == "T" or k.startswith("T_")]
            if len(keys) != 1:
                raise InputError(source, "JSON must hold exactly one 'T' or 'T_a_b' key with a 4x4 matrix")
            value = value[keys[0]]
        try:
            numbers = np.asarray(value, dtype=float).ravel() if value is not None else np.array([])
        except (TypeError, ValueError):
            raise InputError(source, "expected 16 numbers (4x4) or 6 numbers (x y z roll pitch yaw) in the JSON") from None
    else:
        try:
            numbers = np.array([float(tok) for tok in text.replace(",", " ").split()])
        except ValueError:
            raise InputError(source, "expected 16 numbers (4x4) or 6 numbers (x y z roll pitch yaw)") from None
    if not np.all(np.isfinite(numbers)):
        raise InputError(source, "non-finite value in transform")
    if numbers.size == 6:
        return geometry.T_from_xyz_rpy_deg(*numbers)
    if numbers.size == 12:
        numbers = np.concatenate([numbers, [0, 0, 0, 1]])
    if numbers.size != 16:
        raise InputError(source, f"expected 16 numbers (4x4) or 6 (x y z roll pitch yaw), got {numbers.size}")
    T = numbers.reshape(4, 4)
    if not np.all(np.isfinite(T)):
        raise InputError(source, "non-finite value in transform")
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(source, "last row of the 4x4 must be [0, 0, 0, 1]")
    if not geometry.is_rotation(T[:3, :3], tol=1e-5):
        raise InputError(source, "rotation part is not orthonormal with det +1")
    return T


def read_transform(path: str | os.PathLike) -> np.ndarray:
    path = Path(path)
    return parse_transform_text(read_text(path), path)

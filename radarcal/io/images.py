"""Image reading with clear errors."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from radarcal.errors import InputError

__all__ = ["read_image"]


def read_image(path: str | os.PathLike, grayscale: bool = False) -> np.ndarray:
    """Read an image (uint8 BGR, or gray with ``grayscale=True``); InputError for missing/corrupt files."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image not found")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise InputError(path, "empty file")
    img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        raise InputError(path, "not a readable image (corrupt or unsupported format)")
    return img

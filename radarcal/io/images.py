"""Image files and encoded image bytes: read and decode with clear errors, write."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from radarcal.errors import InputError

__all__ = ["read_image", "decode_image", "write_image"]


def read_image(path: str | os.PathLike, grayscale: bool = False) -> np.ndarray:
    """Read an image (uint8 BGR, or gray with ``grayscale=True``); InputError for missing/corrupt files."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image not found")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise InputError(path, "empty file")
    img = decode_image(data, grayscale)
    if img is None or img.size == 0:
        raise InputError(path, "not a readable image (corrupt or unsupported format)")
    return img


def decode_image(data: bytes | np.ndarray, grayscale: bool = False) -> np.ndarray | None:
    """Encoded image bytes (JPEG, PNG, ...) as uint8 BGR (gray with ``grayscale=True``); None when they do not decode."""
    buf = data if isinstance(data, np.ndarray) else np.frombuffer(data, np.uint8)
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_COLOR)


def write_image(path: str | os.PathLike, img: np.ndarray, what: str = "image") -> None:
    """Write ``img`` in the format of the file's suffix (.png, .jpg, ...); InputError ``cannot write <what>``."""
    if not cv2.imwrite(str(path), img):
        raise InputError(path, f"cannot write {what}")

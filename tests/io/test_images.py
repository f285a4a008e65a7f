"""Image reading with clear errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io import read_image
from radarcal.io.images import decode_image, write_image


def test_read_png_and_gray(tmp_path):
    img = (np.arange(48 * 64 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
    assert cv2.imwrite(str(tmp_path / "a.png"), img)
    assert np.array_equal(read_image(tmp_path / "a.png"), img)
    gray = read_image(tmp_path / "a.png", grayscale=True)
    assert gray.shape == (48, 64) and np.abs(gray.astype(int) - cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)).max() <= 1


def test_real_image(shared):
    img = read_image(shared("opencv_stereo_chessboard") / "left01.jpg", grayscale=True)
    assert img.shape == (480, 640)


@pytest.mark.parametrize("data, msg", [(b"", "empty file"), (b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "not a readable image"), (b"hello", "not a readable image")])
def test_bad_images(tmp_path, data, msg):
    p = tmp_path / "bad.png"
    p.write_bytes(data)
    with pytest.raises(InputError) as e:
        read_image(p)
    assert e.value.source == str(p) and msg in e.value.message


def test_missing_image(tmp_path):
    with pytest.raises(InputError, match="image not found"):
        read_image(tmp_path / "nope.png")


def test_decode_encoded_bytes_and_write(tmp_path):
    img = (np.arange(48 * 64 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
    ok, png = cv2.imencode(".png", img)
    assert ok and np.array_equal(decode_image(png.tobytes()), img)
    assert decode_image(b"hello") is None  # what a recorded frame that does not decode gives (the loop reports it)
    write_image(tmp_path / "w.png", img, "minimap image")
    assert np.array_equal(read_image(tmp_path / "w.png"), img)
    with pytest.raises(InputError, match="cannot write minimap image"):
        write_image(tmp_path / "no-such-folder" / "w.png", img, "minimap image")

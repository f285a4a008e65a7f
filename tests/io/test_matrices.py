"""4x4 transform files: JSON, text, 3x4, x y z roll pitch yaw."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry as g
from radarcal.errors import InputError
from radarcal.io import read_transform
from radarcal.io.matrices import parse_transform_text

T_REF = g.T_from_xyz_rpy_deg(0.05, -0.12, 0.03, -90.1, 0.3, -89.7)


@pytest.mark.parametrize(
    "name, text",
    [
        ("named.json", json.dumps({"T_cam0_lidar0": T_REF.tolist()})),
        ("plain_T.json", json.dumps({"T": T_REF.tolist(), "note": "from the CAD model"})),
        ("bare.json", json.dumps(T_REF.tolist())),
        ("rows.txt", "\n".join(" ".join(repr(float(v)) for v in row) for row in T_REF)),
        ("commas.txt", ",\n".join(", ".join(repr(float(v)) for v in row) for row in T_REF)),
        ("three_rows.txt", "\n".join(" ".join(repr(float(v)) for v in row) for row in T_REF[:3])),
    ],
)
def test_matrix_files(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    assert np.array_equal(read_transform(p), T_REF)  # repr() keeps every bit


def test_xyz_rpy_degrees(tmp_path):
    p = tmp_path / "pose.txt"
    p.write_text("0.05 -0.12 0.03 -90.1 0.3 -89.7\n")
    T = read_transform(p)
    R = g.rpy_deg_to_R(-90.1, 0.3, -89.7)
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [0.05, -0.12, 0.03])


def test_kitti_tr_velo_to_cam_as_text(shared, tmp_path):
    """The 3x4 Tr_velo_to_cam line of the real KITTI calibration (SOURCE.md) read as 12 numbers."""
    calib = (shared("kitti_000008") / "calib_000008.txt").read_text().splitlines()
    line = next(ln for ln in calib if ln.startswith("Tr_velo_to_cam"))
    p = tmp_path / "tr.txt"
    p.write_text(line.split(":", 1)[1])
    T = read_transform(p)
    np.testing.assert_allclose(T[0], [0.0075337449, -0.9999713898, -0.0006166020, -0.0040697660], atol=1e-9)
    np.testing.assert_allclose(T[2], [0.9998620749, 0.0075237900, 0.0148075502, -0.2717806101], atol=1e-9)
    assert np.array_equal(T[3], [0, 0, 0, 1])


@pytest.mark.parametrize(
    "text, msg",
    [
        ("1 2 3", "expected 16 numbers (4x4) or 6 (x y z roll pitch yaw), got 3"),
        ("one two three", "expected 16 numbers (4x4) or 6 numbers"),
        ("{not json", "not valid JSON"),
        (json.dumps({"T_a_b": np.eye(4).tolist(), "T_c_d": np.eye(4).tolist()}), "exactly one 'T' or 'T_a_b' key"),
        (json.dumps({"T": "identity"}), "expected 16 numbers"),
        (json.dumps([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]), "last row of the 4x4 must be [0, 0, 0, 1]"),
        (json.dumps((np.eye(4) * [2, 1, 1, 1]).tolist()), "rotation part is not orthonormal"),
        ("1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1", "non-finite value"),
        ("0 0 0 0 nan 0", "non-finite value"),
        ("", "expected 16 numbers"),
    ],
)
def test_rejections(tmp_path, text, msg):
    p = tmp_path / "T.txt"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_transform(p)
    assert e.value.source == str(p) and msg in e.value.message, e.value.message


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_transform(tmp_path / "nope.txt")
    (tmp_path / "bin").write_bytes(b"\xff\xfe\x81")
    with pytest.raises(InputError, match="cannot read file as text"):
        read_transform(tmp_path / "bin")


def test_parse_text_directly():
    assert np.array_equal(parse_transform_text("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"), np.eye(4))

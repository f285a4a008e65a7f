"""Mesh reader: STL (binary, ASCII), OBJ, PLY (ASCII, binary) give the same triangles; units from the extent; bad
files are one InputError naming the file."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io.meshes import read_mesh
from radarcal.synth.lidar_field import box_mesh


def _tri_set(m):
    """(T,9) canonical triangles: corners sorted within each triangle, rows sorted (winding/start do not matter)."""
    c = np.round(m.corners, 4)
    rows = np.array([np.concatenate(sorted(map(tuple, t))) for t in c])
    return rows[np.lexsort(rows.T[::-1])]


def _write_stl_binary(path, corners):
    rec = np.zeros(len(corners), dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]))
    rec["v"] = corners
    path.write_bytes(b"\0" * 80 + np.uint32(len(corners)).tobytes() + rec.tobytes())


def _write_stl_ascii(path, corners):
    lines = ["solid box"]
    for t in corners:
        lines += ["facet normal 0 0 0", " outer loop"] + [f"  vertex {x:.6f} {y:.6f} {z:.6f}" for x, y, z in t] + [" endloop", "endfacet"]
    path.write_text("\n".join(lines + ["endsolid box"]) + "\n")


def _write_obj(path, m):
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in m.vertices) + "".join(f"f {a + 1}/1 {b + 1}/1 {c + 1}/1\n" for a, b, c in m.triangles))


def _write_ply(path, m, binary):
    head = f"ply\nformat {'binary_little_endian' if binary else 'ascii'} 1.0\nelement vertex {len(m.vertices)}\nproperty float x\nproperty float y\nproperty float z\nelement face {len(m.triangles)}\nproperty list uchar int vertex_indices\nend_header\n"
    if binary:
        f = np.zeros(len(m.triangles), dtype=np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
        f["n"], f["i"] = 3, m.triangles
        path.write_bytes(head.encode() + m.vertices.astype("<f4").tobytes() + f.tobytes())
    else:
        path.write_text(head + "".join(f"{x} {y} {z}\n" for x, y, z in m.vertices) + "".join(f"3 {a} {b} {c}\n" for a, b, c in m.triangles))


@pytest.fixture
def box():
    return box_mesh(np.array([1.0, 2.0, 0.0]), np.array([0.6, 0.5, 0.4]), 0.3)


def test_all_formats_same_triangles(tmp_path, box):
    ref = _tri_set(box)
    _write_stl_binary(tmp_path / "a.stl", box.corners)
    _write_stl_ascii(tmp_path / "b.stl", box.corners)
    _write_obj(tmp_path / "c.obj", box)
    _write_ply(tmp_path / "d.ply", box, binary=False)
    _write_ply(tmp_path / "e.ply", box, binary=True)
    for name in ("a.stl", "b.stl", "c.obj", "d.ply", "e.ply"):
        m = read_mesh(tmp_path / name)
        assert m.units == "m" and len(m.triangles) == 12, name
        np.testing.assert_allclose(_tri_set(m), ref, atol=2e-4, err_msg=name)
        np.testing.assert_allclose(np.sort(m.areas()), np.sort(box.areas()), atol=1e-5)


def test_millimetres_detected_and_forced(tmp_path, box):
    big = box_mesh(np.array([14000.0, 7500.0, 0.0]), np.array([28000.0, 15000.0, 400.0]), 0.0)
    _write_stl_binary(tmp_path / "mm.stl", big.corners)
    m = read_mesh(tmp_path / "mm.stl")
    assert m.units == "mm"
    np.testing.assert_allclose(m.vertices.max(0) - m.vertices.min(0), [28.0, 15.0, 0.4], atol=1e-3)
    assert read_mesh(tmp_path / "mm.stl", units="m").vertices.max() > 1000
    _write_stl_binary(tmp_path / "m.stl", box.corners)
    assert read_mesh(tmp_path / "m.stl", units="mm").vertices.max() < 0.01


@pytest.mark.parametrize("name,data,msg", [
    ("x.stl", b"hello, this is not a mesh at all" * 10, "not a mesh"),
    ("x.obj", b"# nothing\n", "not a mesh"),
    ("x.ply", b"ply\nformat ascii 1.0\nend_header\n", "not a mesh"),
    ("x.txt", b"1 2 3", "not a mesh file"),
    ("x.stl", b"solid s\nendsolid s\n", "not a mesh"),
])
def test_bad_files_one_line(tmp_path, name, data, msg):
    p = tmp_path / name
    p.write_bytes(data)
    with pytest.raises(InputError) as e:
        read_mesh(p)
    assert str(p) in str(e.value) and msg in str(e.value) and "\n" not in str(e.value)


def test_missing_and_bad_units(tmp_path):
    with pytest.raises(InputError, match="mesh file not found"):
        read_mesh(tmp_path / "nope.stl")
    with pytest.raises(InputError, match="--field-units"):
        read_mesh(tmp_path / "nope.stl", units="inch")

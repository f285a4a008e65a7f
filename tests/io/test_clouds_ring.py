"""The ``ring`` field of spinning multi-beam LiDAR clouds: read by every PCD path (ascii, binary_compressed through the
LZF decoder) and from the real opencalib clouds."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.io import read_cloud, write_pcd

o3d = pytest.importorskip("open3d", reason="open3d is needed to write reference clouds")


def _write(path, n=3000, seed=1, ascii=False, compressed=True):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-50, 50, (n, 3)).astype(np.float32)
    inten = rng.integers(0, 255, n).astype(np.float32)
    ring = rng.integers(0, 64, n).astype(np.uint16)
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(pts)
    pc.point.intensity = o3d.core.Tensor(inten[:, None])
    pc.point.ring = o3d.core.Tensor(ring[:, None])
    assert o3d.t.io.write_point_cloud(str(path), pc, write_ascii=ascii, compressed=compressed)
    return pts, inten, ring


def test_ring_binary_compressed(tmp_path):
    pts, inten, ring = _write(tmp_path / "c.pcd")
    c = read_cloud(tmp_path / "c.pcd")
    assert np.array_equal(c.points, pts) and np.array_equal(c.intensity, inten)
    assert c.ring is not None and c.ring.dtype == np.int32 and np.array_equal(c.ring, ring.astype(np.int32))


def test_ring_ascii_and_absent(tmp_path):
    pts, _, ring = _write(tmp_path / "a.pcd", n=500, ascii=True, compressed=False)
    c = read_cloud(tmp_path / "a.pcd")
    assert np.allclose(c.points, pts, atol=1e-4) and np.array_equal(c.ring, ring.astype(np.int32))
    write_pcd(tmp_path / "b.pcd", pts)
    assert read_cloud(tmp_path / "b.pcd").ring is None


def test_ring_of_the_opencalib_clouds(shared):
    root = shared("opencalib_road_64beam")
    for name in ("auto", "calibanything_1"):  # 85,546 and 101,340 points, binary_compressed
        c = read_cloud(root / name / "calib.pcd")
        assert c.ring is not None and len(c.ring) == len(c.points)
        assert c.ring.min() == 0 and c.ring.max() == 63
        # one ring is one cone: its elevation is constant to < 0.05 deg (SOURCE.md: 64-ring spinning LiDAR)
        el = np.degrees(np.arctan2(c.points[:, 2], np.hypot(c.points[:, 0], c.points[:, 1])))
        near = np.linalg.norm(c.points, axis=1) > 2.0
        for r in (0, 20, 40, 63):
            m = (c.ring == r) & near
            assert np.ptp(np.percentile(el[m], [5, 95])) < 0.05

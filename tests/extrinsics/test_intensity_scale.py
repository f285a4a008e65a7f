"""Reflectivity-edge thresholds follow the cloud's intensity encoding (0..1, 0..255, 0..65535), not absolute units."""

from __future__ import annotations

import numpy as np

from radarcal.extrinsics.edges import lidar_intensity_edges, lidar_scan_intensity_edges, to_8bit_intensity


def _striped_sweep(seed: int = 0):
    """A flat road 2 m below a spinning LiDAR with bright painted stripes every 2 m across x (8-bit reflectivity)."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.linspace(-24, -6, 32))
    az = np.radians(np.arange(-60, 60, 0.1))
    E, A = np.meshgrid(el, az, indexing="ij")
    r = 2.0 / np.sin(-E)
    P = np.column_stack([(r * np.cos(E) * np.cos(A)).ravel(), (r * np.cos(E) * np.sin(A)).ravel(), np.full(E.size, -2.0)])
    P += rng.normal(scale=0.01, size=P.shape)
    stripe = (np.floor(P[:, 0] / 1.0) % 2 == 0) & (P[:, 0] < 20)
    I = np.where(stripe, 180.0, 30.0) + rng.normal(scale=3.0, size=len(P))
    ring = np.repeat(np.arange(32), len(az))
    return P, np.clip(I, 0, 255), ring


def test_scale_detection():
    assert np.allclose(to_8bit_intensity(np.array([0.0, 0.5, 1.0])), [0, 127.5, 255])
    assert np.allclose(to_8bit_intensity(np.array([0.0, 17.0, 254.0])), [0, 17, 254])
    assert np.allclose(to_8bit_intensity(np.array([0.0, 65535.0])), [0, 255])


def test_scan_edges_do_not_depend_on_the_encoding():
    P, I, ring = _striped_sweep()
    e8 = lidar_scan_intensity_edges(P, I, ring)
    e1 = lidar_scan_intensity_edges(P, I / 255.0, ring)  # as KITTI stores reflectance
    e16 = lidar_scan_intensity_edges(P, I * 257.0, ring)
    assert len(e8.points) > 50
    assert len(e1.points) == len(e8.points) == len(e16.points)
    assert np.allclose(e1.points, e8.points) and np.allclose(e16.points, e8.points)
    # the stripe borders are at integer x: every sample lies on one
    near = np.abs(e8.points[:, 0] - np.round(e8.points[:, 0]))
    assert np.median(near) < 0.1


def test_dense_edges_do_not_depend_on_the_encoding():
    P, I, _ = _striped_sweep(1)
    keep = np.linalg.norm(P, axis=1) < 8
    a = lidar_intensity_edges(P[keep], I[keep], radius=0.3)
    b = lidar_intensity_edges(P[keep], I[keep] / 255.0, radius=0.3)
    assert len(a.points) > 0 and len(a.points) == len(b.points) and np.allclose(a.points, b.points)

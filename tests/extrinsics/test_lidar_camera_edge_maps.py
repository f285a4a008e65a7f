"""Image-edge maps of the edge refinement: the orientation-aware chamfer map and the LSD + Canny union, checked
against a drawn image whose edges are known exactly."""

from __future__ import annotations

import numpy as np

from radarcal.extrinsics.edges import image_edges
from radarcal.extrinsics.refine import RefineOptions, _valley_directions


def _cross_image():
    # a bright vertical bar (borders at x = 199.5 / 219.5) and a bright horizontal bar (borders at y = 299.5 / 319.5)
    img = np.full((480, 640), 40, np.uint8)
    img[60:420, 200:220] = 200
    img[300:320, 300:600] = 200
    return img


def test_oriented_distance_only_counts_parallel_edges():
    ie = image_edges(_cross_image(), method="canny")
    od = ie.oriented_distance(12)
    assert od.shape == (12, 480, 640)
    # a pixel on the horizontal bar's upper border, far from the vertical bar
    v, u = 300, 450
    assert ie.dist[v, u] < 1.5
    horizontal_bin, vertical_bin = 0, 6  # edge direction angle 0 deg (along x) and 90 deg (along y)
    assert od[horizontal_bin, v, u] < 1.5
    # for a vertical LiDAR edge there, the nearest *parallel* image edge is the horizontal bar's right end (x = 599.5,
    # 149.5 px away; the vertical bar's border is 230.5 px away)
    assert abs(od[vertical_bin, v, u] - (599.5 - 450)) < 3.0
    assert ie.oriented_distance(12) is od  # computed once per image


def test_lsd_canny_union_keeps_both_detectors():
    img = _cross_image()
    a, b, both = image_edges(img, method="lsd"), image_edges(img, method="canny"), image_edges(img, method="lsd+canny")
    assert len(both.uv) == len(a.uv) + len(b.uv)
    assert np.all(both.dist <= np.minimum(a.dist, b.dist) + 1e-4)
    # every sample of the union lies on a bar border (within 1.5 px)
    on_v = (np.abs(both.uv[:, 0] - 199.5) < 1.5) | (np.abs(both.uv[:, 0] - 219.5) < 1.5)
    on_h = (np.abs(both.uv[:, 1] - 299.5) < 1.5) | (np.abs(both.uv[:, 1] - 319.5) < 1.5)
    assert np.mean(on_v | on_h) > 0.97


def test_valley_restarts_include_the_optical_axis():
    assert any(np.allclose(d, [0, 0, 0, 0, 0, 1]) for d in _valley_directions([], np.eye(4), RefineOptions()))
    assert len(_valley_directions([], np.eye(4), RefineOptions(valley_depth=False))) == 2

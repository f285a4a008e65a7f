"""Reflectivity (intensity) edges of spinning multi-beam sweeps: a hand-made scan, a generated spinning scene with
painted stripes (truth from the scene definition), and the real opencalib_road_64beam goal (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.edges import LidarEdges, edge_score, image_edges, lidar_scan_edges, lidar_scan_intensity_edges, merge_edges


def _wall_scan(rings=12, az_step_deg=0.2, dist=10.0, stripe=(2.0, 3.0), step_at=None):
    """Rings of a spinning LiDAR hitting a wall x = dist; a bright painted band for y in ``stripe`` (m); optionally
    a depth step (wall moved 2 m back) for y > ``step_at``."""
    az = np.radians(np.arange(-30.0, 30.0, az_step_deg))
    el = np.radians(np.linspace(-3.0, 3.0, rings))
    A, E = np.meshgrid(az, el)
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    x = np.full(len(d), dist)
    if step_at is not None:
        y0 = dist * d[:, 1] / d[:, 0]
        x = np.where(y0 > step_at, dist + 2.0, x)
    P = d * (x / d[:, 0])[:, None]
    I = np.where((P[:, 1] > stripe[0]) & (P[:, 1] < stripe[1]), 120.0, 30.0)
    ring = np.repeat(np.arange(rings), len(az))
    return P, I, ring


def test_painted_band_borders_are_found_with_vertical_directions():
    P, I, ring = _wall_scan()
    for rg in (ring, None):  # the ring field, or elevation bins
        E = lidar_scan_intensity_edges(P, I, rg, max_range=None)
        assert len(E.points) >= 20
        near = np.minimum(np.abs(E.points[:, 1] - 2.0), np.abs(E.points[:, 1] - 3.0))
        spacing = 10.0 * np.radians(0.2)  # between neighbouring points on the wall
        assert np.all(near < spacing)
        assert np.all(np.abs(E.dirs[:, 2]) > 0.98)  # the band borders run vertically across the rings
        # both borders, every ring
        assert (np.abs(E.points[:, 1] - 2.0) < spacing).sum() >= 10 and (np.abs(E.points[:, 1] - 3.0) < spacing).sum() >= 10


def test_depth_step_without_paint_is_not_an_intensity_edge():
    P, _, ring = _wall_scan(step_at=-1.0)
    I = np.full(len(P), 50.0)
    assert len(lidar_scan_intensity_edges(P, I, ring, max_range=None).points) == 0
    assert len(lidar_scan_edges(P, I, ring, "depth", max_range=None).points) > 0  # the depth edges see it
    both = lidar_scan_edges(P, I, ring, "depth+intensity", max_range=None)
    assert len(both.points) == len(lidar_scan_edges(P, I, ring, "depth", max_range=None).points)
    with pytest.raises(ValueError):
        lidar_scan_edges(P, None, ring, "intensity")
    assert len(merge_edges(LidarEdges(np.zeros((0, 3)), np.zeros((0, 3)))).points) == 0


def test_generated_spinning_scene_intensity_edges_on_stripe_borders():
    pytest.importorskip("open3d")
    from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene

    # one 0.1 s sweep of a 64-beam LiDAR at 1.2 M points/s (0.19 deg azimuth steps, like a real 64-beam sensor)
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=2, lidar="spinning", duration_s=0.1, point_rate=1.2e6, supersample=1))
    E = lidar_scan_intensity_edges(s.points, s.intensity)
    assert len(E.points) > 100
    # ground (z = -lidar_height) carries lane stripes across y: period 3.7 m, painted for the first 12 % of it
    # (radarcal/synth/lidar_camera.py) -> borders at y = 3.7 k and 3.7 k + 0.444
    g = -s.params["lidar_height_m"]
    ground = E.points[:, 2] < g + 0.15
    ph = np.mod(E.points[ground, 1], 3.7)
    d = np.minimum.reduce([ph, 3.7 - ph, np.abs(ph - 0.444)])
    assert ground.sum() >= 40
    assert (d < 0.1).mean() > 0.6  # chance level: 0.4 m of every 3.7 m = 11 %
    # at the true extrinsic they land on image edges; 1 deg off they do not
    ie = image_edges(s.image, method="canny", min_length=20)
    at_truth, n = edge_score(s.camera, s.T_cam_lidar, E, ie)
    off, _ = edge_score(s.camera, geometry.perturb_T(s.T_cam_lidar, 1.0, 0.0, np.random.default_rng(0)), E, ie)
    assert n > 80 and at_truth < 2.5 and off > at_truth + 2.0


@pytest.mark.slow
def test_opencalib_goal_intensity_rotation_only(shared):
    """Issue 5 goal on opencalib_road_64beam: started at the shipped reference, the intensity-edge rotation-only
    refinement ends no worse than the reference by the same edge score (intensity edges vs Canny, the same edges for
    both); started 1 deg / 5 cm off it lands within 0.5 deg of the reference with a score within 0.25 px of the
    reference's (the 5 cm start offset stays: rotation only); it never claims convergence more than 0.5 deg away."""
    shared("opencalib_road_64beam")
    from benchmarks.lidar_camera import opencalib_runs

    rows = opencalib_runs(names=("auto", "manual"), configs=("intensity rot-only",), starts=((0.0, 0.0), (1.0, 0.05)), seeds=(1,))
    assert len(rows) == 4
    for r in rows:
        assert not (r["converged"] and r["rot_deg"] > 0.5), r
        if r["start_deg"] == 0:
            assert r["score_result"][0] <= r["score_ref"][0] and r["rot_deg"] < 0.5, r
        else:
            assert r["rot_deg"] < 0.5 and r["score_result"][0] <= r["score_ref"][0] + 0.25, r

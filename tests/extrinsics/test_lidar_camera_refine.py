"""Targetless edge refinement on generated scenes (truth known) and on the real data sets (slow)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.edges import edge_score, image_edges, lidar_edges, lidar_intensity_edges, merge_edges
from radarcal.extrinsics.refine import EdgeScene, RefineOptions, refine_edges
from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene


@pytest.fixture(scope="module")
def scene4():
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=4, duration_s=3.0))
    return s, EdgeScene(s.camera, lidar_edges(s.points), image_edges(s.image))


def test_lidar_edges_lie_on_object_edges(scene4):
    s, sc = scene4
    assert len(sc.lidar.points) > 300
    # projected with the truth, most LiDAR edge samples sit within 2 px of an image edge
    uv, valid, _ = s.camera.project_from(s.T_cam_lidar, sc.lidar.points)
    ins = valid & s.camera.in_image(uv, 2)
    ij = np.round(uv[ins]).astype(int)
    d = sc.image.dist[ij[:, 1], ij[:, 0]]
    assert np.median(d) <= 1.0 and np.mean(d <= 2.0) > 0.5  # some creases have no image edge (equal shading)
    # and the score rises when the extrinsic is wrong
    s_true = edge_score(s.camera, s.T_cam_lidar, sc.lidar, sc.image)[0]
    s_bad = edge_score(s.camera, geometry.perturb_T(s.T_cam_lidar, 1.0, 0.0, np.random.default_rng(0)), sc.lidar, sc.image)[0]
    assert s_bad > s_true + 1.0


def test_refine_from_3deg_10cm(scene4):
    s, sc = scene4
    r = refine_edges([sc], s.T_init)
    deg, m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert r.converged, r.message
    assert deg < 0.1 and m < 0.02, (deg, m)
    assert r.score_after < r.score_before
    assert np.all(np.isfinite(r.sigma)) and np.degrees(r.sigma[:3]).max() < 0.1
    assert set(r.profiles) == {"rx", "ry", "rz", "tx", "ty", "tz"}
    # the block bootstrap keeps the correlation along each edge: not below the Jacobian figure (the reported sigma is
    # floored at it: the robust 16-84 % spread was 0.0124 deg about rx vs the Jacobian's 0.0132 deg here), wider on
    # the translation, and the true error (left-multiplied, camera frame - the parametrisation of both sigmas) is
    # within a few of its sigmas
    sb = r.sigma_bootstrap
    assert np.all(np.isfinite(sb)) and np.all(sb >= r.sigma) and np.all(sb[3:] > r.sigma[3:]), (sb, r.sigma)
    err = geometry.T_to_rotvec(s.T_cam_lidar @ np.linalg.inv(r.T_cam_lidar))
    assert np.max(np.abs(err) / sb) < 10, np.abs(err) / sb
    # cost profiles have their minimum near the solution
    for name, (offs, cost) in r.profiles.items():
        assert abs(np.argmin(cost) - len(cost) // 2) <= 2, name


def test_parallel_edges_warn(scene4):
    s, sc = scene4
    # keep only LiDAR edges running left-right (image-horizontal lines): the observability check must complain
    horiz = np.abs(sc.lidar.dirs[:, 1]) > 0.97
    from radarcal.extrinsics.edges import LidarEdges

    one_dir = LidarEdges(sc.lidar.points[horiz], sc.lidar.dirs[horiz])
    r = refine_edges([EdgeScene(s.camera, one_dir, sc.image)], s.T_cam_lidar, RefineOptions(coarse_search_deg=0))
    assert any("parallel" in w or "conditioned" in w for w in r.warnings), r.warnings


def test_implausible_centre_move_is_not_converged(scene4):
    # the start is 10 cm off, so the right answer moves the camera centre ~10 cm: with a 1 cm limit it must say no
    s, sc = scene4
    r = refine_edges([sc], s.T_init, RefineOptions(max_translation_move_m=0.01, coarse_search_deg=0, stability_checks=0))
    assert not r.converged and "camera centre moved" in r.message


def test_weakly_constrained_is_not_converged(scene4):
    # a bootstrap limit below what any real scene reaches: the verdict must refuse, naming the reason
    s, sc = scene4
    r = refine_edges([sc], s.T_init, RefineOptions(max_bootstrap_sigma_m=1e-5, coarse_search_deg=0, stability_checks=0))
    assert not r.converged and "weakly constrained" in r.message, r.message
    assert r.sigma_bootstrap[3:].max() > 1e-5


def test_far_off_start_is_reported(scene4):
    s, sc = scene4
    T0 = geometry.perturb_T(s.T_cam_lidar, 15.0, 0.5, np.random.default_rng(3))
    r = refine_edges([sc], T0, RefineOptions(coarse_search_deg=2.0))
    deg, m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    # either it really got there, or it must say it did not converge
    assert (deg < 0.2 and m < 0.03) or not r.converged


def test_intensity_edges_lie_on_paint_edges(scene4):
    s, sc = scene4
    li = lidar_intensity_edges(s.points, s.intensity)
    assert len(li.points) > 300
    # projected with the true extrinsic they sit on image edges (paint borders the plane edges cannot see)
    from radarcal.extrinsics.refine import match_edges

    uv, valid, _ = s.camera.project_from(s.T_cam_lidar, li.points)
    n_in = int((valid & s.camera.in_image(uv, 2)).sum())
    idx, _, _, r = match_edges(EdgeScene(s.camera, li, sc.image), s.T_cam_lidar, 3.0)
    assert len(idx) > 0.7 * n_in and np.median(np.abs(r)) < 0.6, (len(idx), n_in, np.median(np.abs(r)))
    # no usable intensity: no edges, no error
    assert len(lidar_intensity_edges(s.points, np.zeros(len(s.points))).points) == 0
    assert len(lidar_intensity_edges(s.points, None).points) == 0


def _planes_and_paint(s):
    return EdgeScene(s.camera, merge_edges(lidar_edges(s.points), lidar_intensity_edges(s.points, s.intensity)), image_edges(s.image))


def test_refine_with_intensity_seed6():
    # seed 6 is one of the scenes where plane edges alone end ~0.6 deg off ("not converged")
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=6, duration_s=4.0))
    r = refine_edges([_planes_and_paint(s)], s.T_init)
    deg, m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert r.converged and deg < 0.1 and m < 0.02, (deg, m, r.message)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_refine_with_intensity_seeds_slow(seed):
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=seed, duration_s=4.0, init_deg=6.0, init_m=0.2))
    r = refine_edges([_planes_and_paint(s)], s.T_init)
    deg, m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert r.converged and deg < 0.1 and m < 0.02, (deg, m, r.message)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 3, 4])
def test_refine_seeds_slow(seed):
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=seed, duration_s=4.0))
    r = refine_edges([EdgeScene(s.camera, lidar_edges(s.points), image_edges(s.image))], s.T_init)
    deg, m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert deg < 0.1 and m < 0.02


@pytest.mark.slow
@pytest.mark.shared
@pytest.mark.xfail(strict=True, reason="issue-5 mlcc line not met: single pairs land 0.9-3 deg from the reference, the dense joint solve 0.51-0.59 deg / 6-10 cm; both cameras find the same ~0.5 deg pitch offset from the reference (docs/lidar_camera.md)")
def test_mlcc_from_perturbed_reference(shared):
    from radarcal.io import import_camera, read_cloud, read_image

    D = shared("mlcc_livox_mid100_scene2")
    p = json.loads((D / "calib/pairs_T_cam_lidar.json").read_text())["pairs"][0]
    cam, _ = import_camera(D / p["intrinsics"])
    T_ref = np.array(p["T_cam_lidar"])
    le = lidar_edges(read_cloud(D / p["cloud"]).points, voxel=0.5, min_points=8, max_range=60)
    sc = EdgeScene(cam, le, image_edges(read_image(D / p["image"])))
    r = refine_edges([sc], geometry.perturb_T(T_ref, 3.0, 0.10, np.random.default_rng(0)), RefineOptions(translation_prior_m=0.3))
    deg, m = geometry.pose_error(r.T_cam_lidar, T_ref)
    assert deg < 0.5 and m < 0.05, (deg, m)
    assert r.score_after <= edge_score(cam, T_ref, le, sc.image)[0]

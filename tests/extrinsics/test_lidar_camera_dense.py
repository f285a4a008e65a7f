"""Dense edge correlation (radarcal.extrinsics.dense): generated scene (truth known) and mlcc (slow, real reference)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.dense import DenseOptions, DenseScene, dense_score, image_energy, refine_dense, view_depth_edges
from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene


@pytest.fixture(scope="module")
def synth4():
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=4, duration_s=3.0))
    return s, DenseScene(s.camera, s.points.astype(float), image_energy(s.image))


def test_view_depth_edges_lie_on_image_edges(synth4):
    s, sc = synth4
    e = view_depth_edges(s.camera, s.T_cam_lidar, sc.points)
    assert len(e.points) > 1000
    # at the truth the depth-edge points sit on object boundaries of the rendered image: the object id changes
    # within R px of most of them (the edge point is on the near object, the far side is another object or sky)
    uv, valid, _ = s.camera.project_from(s.T_cam_lidar, e.points)
    ij = np.round(uv[valid]).astype(int)
    R = 4
    ids = np.pad(s.id_image, R, mode="edge")
    centre = ids[ij[:, 1] + R, ij[:, 0] + R]
    changes = np.zeros(len(ij), bool)
    for dy in range(-R, R + 1):
        for dx in range(-R, R + 1):
            changes |= ids[ij[:, 1] + R + dy, ij[:, 0] + R + dx] != centre
    assert np.mean(changes) > 0.7  # measured 0.76 (seed 4); ground-vs-far-ground steps keep one id
    # and the dense score drops when the extrinsic is wrong
    good = dense_score(s.camera, s.T_cam_lidar, e, sc.energy, 1.0)
    bad = dense_score(s.camera, geometry.perturb_T(s.T_cam_lidar, 1.0, 0.0, np.random.default_rng(0)), e, sc.energy, 1.0)
    assert good > 1.1 * bad  # measured 0.50 vs 0.42


def test_dense_refine_from_3deg_10cm(synth4):
    s, sc = synth4
    r = refine_dense([sc], s.T_init, DenseOptions(stability_checks=0))
    deg, m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert deg < 0.3 and m < 0.03, (deg, m)  # measured 0.15 deg / 1.8 cm (the sparse matcher: 0.04 deg / 1 cm)
    assert r.score > r.score_init


def _mlcc(D, pairs):
    from benchmarks.lidar_camera import mlcc_chained_pairs

    T0, loaded = mlcc_chained_pairs(pairs, D)
    return T0, [DenseScene(cam, P[np.linalg.norm(P, axis=1) < 80] @ C[:3, :3].T + C[:3, 3], image_energy(img), origin=C[:3, 3]) for cam, P, img, C in loaded]


@pytest.mark.slow
@pytest.mark.shared
def test_mlcc_dense_joint(shared):
    """What the dense method measurably achieves on mlcc. Issue-5's 0.5 deg / 5 cm line is NOT asserted (not met:
    left 0.51-0.53 deg / 6-7 cm, right 0.58-0.59 deg / 10 cm, both about -0.5 deg about the camera x axis - see
    docs/lidar_camera.md). Asserted against the reference: the edge score (the sparse method's yardstick) at our
    result is no worse than at the reference for both cameras, and - independent of any error common to both
    cameras - the left-right relative rotation of two independent solves (left pairs, right pairs) is within
    0.25 deg of the reference's (measured 0.09-0.13 deg)."""
    from radarcal.extrinsics.edges import edge_score, image_edges, lidar_edges
    from radarcal.io import import_camera, read_cloud, read_image

    D = shared("mlcc_livox_mid100_scene2")
    meta = json.loads((D / "calib/pairs_T_cam_lidar.json").read_text())["pairs"]
    res = {}
    for name, pairs in (("left", (0, 2, 4, 6, 8, 10)), ("right", (1, 3, 5, 7, 9, 11))):
        T_ref, scenes = _mlcc(D, pairs)
        r = refine_dense(scenes, geometry.perturb_T(T_ref, 3.0, 0.10, np.random.default_rng(0)), DenseOptions(stability_checks=0))
        res[name] = (r.T_cam_lidar, T_ref)
        p = meta[pairs[0]]
        cam, _ = import_camera(D / p["intrinsics"])
        le = lidar_edges(read_cloud(D / p["cloud"]).points, voxel=0.5, min_points=8, max_range=60)
        ie = image_edges(read_image(D / p["image"]))
        assert edge_score(cam, r.T_cam_lidar, le, ie)[0] <= edge_score(cam, T_ref, le, ie)[0], name
        assert geometry.pose_error(r.T_cam_lidar, T_ref)[0] < 1.0  # sanity: nowhere near the 3 deg start
    (TL, TLr), (TR, TRr) = res["left"], res["right"]
    assert geometry.pose_error(TR @ np.linalg.inv(TL), TRr @ np.linalg.inv(TLr))[0] < 0.25

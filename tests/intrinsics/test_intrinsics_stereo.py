"""Stereo extrinsics T_cam1_cam0: synthetic truth and OpenCV's stereo sample (mrcal baseline 83.15 mm)."""

from __future__ import annotations

import cv2
import numpy as np

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.intrinsics.detect import BoardSpec, detect_board, normalise_order, object_points
from radarcal.synth.intrinsics_views import radar_station_camera, simulate_views
from radarcal.intrinsics.solve import calibrate
from radarcal.intrinsics.stereo import pair_by_name, stereo_calibrate


def test_pair_by_name():
    assert pair_by_name(["a/left01.jpg", "a/left03.jpg", "a/left02.jpg"], ["b/right02.jpg", "b/right01.jpg"]) == [(0, 1), (2, 0)]
    assert pair_by_name(["x.png", "y.png"], ["p.png", "q.png"]) == [(0, 0), (1, 1)]


def test_synthetic_stereo_recovers_truth():
    board = BoardSpec("chessboard", 11, 8, 0.03)
    cam0 = radar_station_camera()
    cam1 = Camera(cam0.image_size, cam0.K * [[1.002], [0.998], [1]], cam0.dist)
    T_true = geometry.T_from_xyz_rpy_deg(-0.12, 0.004, 0.002, 0.5, -1.0, 0.3)
    rng = np.random.default_rng(0)
    sim = simulate_views(cam0, board, 40, 0.15, rng, max_tilt_deg=40, fill=(0.3, 0.6), margin_px=40)
    obj, q0, q1 = [], [], []
    for T, o, uv0 in zip(sim.T_cam_board, sim.object_points, sim.image_points):
        uv1, valid, _z = cam1.project_from(T_true @ T, o)
        if valid.all() and cam1.in_image(uv1, 3).all():
            obj.append(o)
            q0.append(uv0)
            q1.append(uv1 + rng.normal(scale=0.15, size=uv1.shape))
    assert len(obj) >= 15
    st = stereo_calibrate(cam0, cam1, obj, q0, q1, refine_intrinsics=False)
    deg, m = geometry.pose_error(st.T_cam1_cam0, T_true)
    assert m < 3 * st.sigma["baseline_m"] + 2e-4 and deg < 0.02
    assert abs(st.baseline_m - np.linalg.norm(T_true[:3, 3])) < 3 * st.sigma["baseline_m"] + 1e-4
    assert st.noise_px < 0.2


def test_joint_stereo_absorbs_intrinsics_errors():
    """Mono intrinsics off by ~0.5 px: fixed-intrinsics stereo is off by far more than its σ; the joint solve
    recovers T_cam1_cam0 and both cameras within its (larger, honest) σ."""
    board = BoardSpec("chessboard", 9, 6, 0.025)
    cam0 = Camera((640, 480), np.array([[500.0, 0, 321.5], [0, 499.6, 238.3], [0, 0, 1]]), np.array([-0.11, 0.075, 0.0004, -0.0003, -0.018]))
    cam1 = Camera((640, 480), np.array([[501.5, 0, 317.2], [0, 501.1, 241.0], [0, 0, 1]]), np.array([-0.10, 0.068, 0.0003, -0.0002, -0.016]))
    T_true = geometry.T_from_xyz_rpy_deg(-0.12, 0.001, -0.002, 0.2, -1.5, 0.1)
    rng = np.random.default_rng(1)
    sim = simulate_views(cam0, board, 60, 0.1, rng, max_tilt_deg=40, fill=(0.35, 0.6), margin_px=10)
    obj, q0, q1 = [], [], []
    for T, o, uv0 in zip(sim.T_cam_board, sim.object_points, sim.image_points):
        uv1, valid, _z = cam1.project_from(T_true @ T, o)
        if valid.all() and cam1.in_image(uv1, 10).all() and len(obj) < 12:
            obj.append(o)
            q0.append(uv0)
            q1.append(uv1 + rng.normal(scale=0.1, size=uv1.shape))
    K0 = cam0.K.copy()
    K0[0, 0] += 0.6
    K0[0, 2] += 0.5
    K1 = cam1.K.copy()
    K1[0, 0] -= 0.6
    K1[1, 2] -= 0.4
    bad0, bad1 = Camera(cam0.image_size, K0, cam0.dist), Camera(cam1.image_size, K1, cam1.dist)
    fixed = stereo_calibrate(bad0, bad1, obj, q0, q1, refine_intrinsics=False)
    joint = stereo_calibrate(bad0, bad1, obj, q0, q1)
    _d, m_fixed = geometry.pose_error(fixed.T_cam1_cam0, T_true)
    _d, m_joint = geometry.pose_error(joint.T_cam1_cam0, T_true)
    assert m_fixed > 5 * fixed.sigma["baseline_m"]
    assert m_joint < 3 * max(joint.sigma["tx"], joint.sigma["ty"], joint.sigma["tz"]) * np.sqrt(3)
    assert m_joint < 0.6 * m_fixed
    assert abs(joint.camera0.fx - cam0.fx) < 3 * joint.sigma0["fx"] and abs(joint.camera1.fx - cam1.fx) < 3 * joint.sigma1["fx"]


def test_opencv_stereo_baseline_matches_mrcal(shared):
    d = shared("opencv_stereo_chessboard")
    board = BoardSpec("chessboard", 9, 6, 0.025)
    L = sorted(d.glob("left*.jpg"))
    R = sorted(d.glob("right*.jpg"))
    dl = [detect_board(cv2.imread(str(p), 0), board) for p in L]
    dr = [detect_board(cv2.imread(str(p), 0), board) for p in R]
    obj = [object_points(board)] * 13
    cl = calibrate(obj, [x.uv for x in dl], (640, 480))
    cr = calibrate(obj, [x.uv for x in dr], (640, 480))
    assert abs(cl.camera.fx - 533.30) < 1.0
    assert abs(cr.camera.fx - 537.4) < 1.0  # SOURCE.md: mrcal/OpenCV adaptive ≈ 537.4
    pairs = pair_by_name([str(p) for p in L], [str(p) for p in R])
    assert len(pairs) == 13
    q1 = [normalise_order(dr[j].uv, board.grid_shape, reference=dl[i].uv) for i, j in pairs]
    st = stereo_calibrate(cl.camera, cr.camera, obj, [dl[i].uv for i, _ in pairs], q1)
    assert abs(st.baseline_m - 0.08315) < 0.0003
    assert st.T_cam1_cam0[0, 3] < 0  # the right camera sits at +x of the left one: p_cam1 = p_cam0 - b
    assert st.rms_px < 0.25

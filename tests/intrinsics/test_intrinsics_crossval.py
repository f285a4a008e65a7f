"""Cross-validation and model choice: synthetic truth and PhotonVision's inconsistent 640x480 chessboard set."""

from __future__ import annotations

import cv2
import numpy as np

from radarcal.camera import Camera
from radarcal.intrinsics.crossval import choose_model, cross_validate, projection_difference
from radarcal.intrinsics.detect import BoardSpec, detect_board, object_points
from radarcal.synth.intrinsics_views import radar_station_camera, simulate_views

BOARD = BoardSpec("chessboard", 11, 8, 0.03)


def test_projection_difference_ignores_a_common_rotation_but_sees_focal_change():
    cam = radar_station_camera()
    u = np.linspace(0, 1279, 20)
    v = np.linspace(0, 1023, 16)
    assert np.nanmax(projection_difference(cam, cam, u, v)) < 1e-6
    K2 = cam.K.copy()
    K2[0, 2] += 3.0  # a principal-point shift is (to first order) a rotation: mostly absorbed
    shifted = Camera(cam.image_size, K2, cam.dist)
    assert np.nanmedian(projection_difference(cam, shifted, u, v)) < 0.2 * 3.0
    K3 = cam.K.copy()
    K3[0, 0] *= 1.01
    K3[1, 1] *= 1.01
    zoomed = Camera(cam.image_size, K3, cam.dist)
    d = projection_difference(cam, zoomed, u, v)
    assert np.nanmax(d) > 5.0 and d[8, 10] < 0.1 * np.nanmax(d)  # small at the centre, grows to the edges


def test_consistent_data_is_consistent():
    sim = simulate_views(radar_station_camera(), BOARD, 24, 0.2, np.random.default_rng(1), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)
    cv = cross_validate(sim.object_points, sim.image_points, (1280, 1024), "pinhole5")
    assert cv.consistent and cv.ratio_median < 2.0


def test_inconsistent_halves_are_flagged():
    """Odd views from a camera with 1 % longer focal length (refocus mid-session): flagged."""
    cam = radar_station_camera()
    K2 = cam.K.copy()
    K2[:2, :2] *= 1.01
    cam2 = Camera(cam.image_size, K2, cam.dist)
    a = simulate_views(cam, BOARD, 12, 0.2, np.random.default_rng(2), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)
    b = simulate_views(cam2, BOARD, 12, 0.2, np.random.default_rng(3), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)
    obj = [o for pair in zip(a.object_points, b.object_points) for o in pair]
    img = [i for pair in zip(a.image_points, b.image_points) for i in pair]
    cv = cross_validate(obj, img, (1280, 1024), "pinhole5")
    assert not cv.consistent and cv.ratio_median > 3


def test_auto_picks_pinhole5_for_a_plain_lens_and_not_for_a_wide_fisheye():
    sim = simulate_views(radar_station_camera(), BOARD, 24, 0.2, np.random.default_rng(4), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)
    choice, cals, _cvs = choose_model(sim.object_points, sim.image_points, (1280, 1024), ("pinhole5", "pinhole8"))
    assert choice.model == "pinhole5"
    fish = Camera((1280, 1024), np.array([[330.0, 0, 640.0], [0, 330.0, 512.0], [0, 0, 1]]), np.array([0.02, -0.01, 0.003, -0.001]), "fisheye")
    simf = simulate_views(fish, BOARD, 24, 0.2, np.random.default_rng(5), max_tilt_deg=40, fill=(0.3, 0.6), margin_px=3)
    choice_f, cals_f, _ = choose_model(simf.object_points, simf.image_points, (1280, 1024))
    assert choice_f.model in ("fisheye", "pinhole8")
    assert cals_f[choice_f.model].rms_px < 0.35
    if "pinhole5" in cals_f:
        assert cals_f["pinhole5"].rms_px > 1.5 * cals_f[choice_f.model].rms_px


def test_photonvision_640x480_inconsistency_flagged(shared):
    """SOURCE.md: the sessions disagree far beyond their formal σ; the halves of the 640x480 chessboard set differ
    by ≈ 10 px against ≈ 0.7 px uncertainty."""
    d = shared("photonvision_lifecam_hd3000") / "chessboard_640x480"
    board = BoardSpec("chessboard", 10, 10, 0.0254)
    dets = [detect_board(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), board) for p in sorted(d.glob("*.png"))]
    assert sum(x.ok for x in dets) == 14
    obj = [object_points(board)[x.ids] for x in dets]
    cv = cross_validate(obj, [x.uv for x in dets], (640, 480), "pinhole5")
    assert not cv.consistent
    assert 5.0 < cv.diff_median_px < 20.0
    assert cv.sigma_median_px < 1.5
    assert cv.ratio_median > 5


def test_opencv_left_set_is_consistent(shared):
    d = shared("opencv_stereo_chessboard")
    board = BoardSpec("chessboard", 9, 6, 0.025)
    dets = [detect_board(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), board) for p in sorted(d.glob("left*.jpg"))]
    obj = [object_points(board)] * len(dets)
    cv = cross_validate(obj, [x.uv for x in dets], (640, 480), "pinhole5")
    assert cv.consistent
    assert cv.diff_median_px < 0.5

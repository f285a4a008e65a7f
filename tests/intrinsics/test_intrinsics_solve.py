"""Solver, σ and rejection against corner-level simulations with known truth (no renderer needed)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from radarcal.intrinsics.detect import BoardSpec
from radarcal.synth.intrinsics_views import radar_station_camera, simulate_good_practice_views, simulate_views
from radarcal.intrinsics.solve import calibrate, projection_uncertainty, residuals, solve_once

BOARD = BoardSpec("chessboard", 14, 10, 0.03)
KEYS = ["fx", "fy", "cx", "cy"]


def _truth(cam):
    return np.array([cam.fx, cam.fy, cam.cx, cam.cy])


def _sim(seed, noise, n_views=30, lens_mm=4.0):
    cam = radar_station_camera(lens_mm)
    return simulate_views(cam, BOARD, n_views, noise, np.random.default_rng(seed), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)


def _good(seed, noise, n_views=30):
    """The good-practice capture plan (close, centred, tilts cycling 0-10°, 20-30°, 45-55°) with the same camera and board."""
    return simulate_good_practice_views(radar_station_camera(), BOARD, n_views, noise, np.random.default_rng(seed))


@pytest.mark.parametrize("seed,noise", [(1, 0.1), (2, 0.2), (3, 0.3)])
def test_accuracy_1280x1024_within_0p3px(seed, noise):
    """Issue 4's target on a good-practice capture plan (30 views, 14x10 board, 4 mm lens)."""
    sim = _good(seed, noise)
    cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size)
    err = cal.params[:4] - _truth(sim.camera)
    assert np.all(np.abs(err) < 0.3), err
    sig = np.array([cal.sigma[k] for k in KEYS])
    assert np.all(np.abs(err) < 3 * sig), (err, sig)
    # the noise estimate recovers the simulated per-coordinate noise
    assert cal.noise_px == pytest.approx(noise, rel=0.1)
    assert np.allclose(cal.camera.dist, sim.camera.dist, atol=0.02)


def test_sigma_matches_opencv_and_scales_with_noise():
    """Our Jacobian (through radarcal's Camera) gives the same σ as OpenCV's stdDeviationsIntrinsics."""
    sim = _sim(5, 0.2, n_views=20)
    cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size, reject=False)
    out = cv2.calibrateCameraExtended([o.astype(np.float32) for o in sim.object_points], [i.astype(np.float32) for i in sim.image_points], sim.camera.image_size, None, None)
    std_cv = out[5].ravel()[:9]
    ours = np.array([cal.sigma[k] for k in ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]])
    assert np.allclose(ours, std_cv, rtol=0.03)
    # residuals through Camera equal OpenCV's projectPoints
    r = residuals(cal.camera, cal.rvecs, cal.tvecs, sim.object_points, sim.image_points)
    uv_cv, _ = cv2.projectPoints(sim.object_points[0], cal.rvecs[0], cal.tvecs[0], cal.camera.K, cal.camera.dist)
    assert np.allclose(sim.image_points[0] - uv_cv.reshape(-1, 2), r[0], atol=1e-6)


def test_truth_inside_3sigma_for_most_seeds():
    seeds = range(10, 16)
    hits = 0
    for seed in seeds:
        sim = _sim(seed, [0.1, 0.2, 0.3][seed % 3], n_views=20)
        cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size)
        sig = np.array([cal.sigma[k] for k in KEYS])
        hits += bool(np.all(np.abs(cal.params[:4] - _truth(sim.camera)) < 3 * sig))
    assert hits >= 5  # >= 95 % expected; the slow sweep checks the rate on many seeds


def test_random_plan_sigma_honest_but_large():
    """The older random plan (boards 40-90 % of the width anywhere, tilts 15-50°): at 0.3 px noise its σ(cx) is
    ≈ 0.24 px (the Cramér-Rao bound), so |Δ| < 0.3 px cannot be promised — but the σ must say so honestly."""
    sim = _sim(3, 0.3)
    cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size)
    sig = np.array([cal.sigma[k] for k in KEYS])
    assert sig[2] > 0.15 and sig[3] > 0.12, sig
    assert np.all(np.abs(cal.params[:4] - _truth(sim.camera)) < 3 * sig)
    good = calibrate(*(lambda g: (g.object_points, g.image_points))(_good(3, 0.3)), sim.camera.image_size)
    assert good.sigma["cx"] < 0.8 * cal.sigma["cx"]  # the good-practice plan halves the variance


@pytest.mark.slow
def test_good_practice_plan_sweep():
    """noise 0.1 / 0.2 / 0.3 px x 20 seeds, 30 views each, good-practice plan: |Δfx|,|Δfy|,|Δcx|,|Δcy| < 0.3 px and
    truth inside 3σ in >= 95 % of the 60 sets; median σ(cx) at 0.3 px < 0.2 px (random plan: ≈ 0.24 px)."""
    truth = _truth(radar_station_camera())
    acc = cov = 0
    sig_cx = []
    for noise in (0.1, 0.2, 0.3):
        for seed in range(20):
            sim = _good(seed, noise)
            cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size)
            sig = np.array([cal.sigma[k] for k in KEYS])
            err = np.abs(cal.params[:4] - truth)
            acc += bool(np.all(err < 0.3))
            cov += bool(np.all(err < 3 * sig))
            if noise == 0.3:
                sig_cx.append(sig[2])
    assert acc >= 57, acc
    assert cov >= 57, cov
    assert np.median(sig_cx) < 0.2, np.median(sig_cx)


@pytest.mark.slow
def test_truth_inside_3sigma_sweep():
    """Coverage of the reported 3σ over 60 seeds (noise 0.1-0.3 px, 20-30 views): >= 95 %."""
    hits, n = 0, 60
    worst = []
    for seed in range(100, 100 + n):
        rng = np.random.default_rng(seed)
        sim = _sim(seed, float(rng.uniform(0.1, 0.3)), n_views=int(rng.integers(20, 31)))
        cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size)
        sig = np.array([cal.sigma[k] for k in KEYS])
        z = np.abs(cal.params[:4] - _truth(sim.camera)) / sig
        worst.append(z.max())
        hits += bool(np.all(z < 3))
    assert hits / n >= 0.95, sorted(worst)[-5:]


def _bent_view(sim, v=3, amplitude=6.0):
    """A badly detected view: the corners of every row bent by up to ``amplitude`` px (mis-refined corners)."""
    imgs = [i.copy() for i in sim.image_points]
    g = imgs[v].reshape(BOARD.rows, BOARD.cols, 2)
    g[..., 1] += amplitude * np.linspace(-1, 1, BOARD.cols)[None, :] ** 2
    imgs[v] = g.reshape(-1, 2)
    return imgs


@pytest.mark.parametrize("seed", [100, 101, 102])
def test_bad_view_rejected_plain_opencv_is_off(seed):
    sim = _sim(seed, 0.2, n_views=25)
    imgs = _bent_view(sim)
    truth = _truth(sim.camera)
    _rms, K, _d, _r, _t = cv2.calibrateCamera([o.astype(np.float32) for o in sim.object_points], [i.astype(np.float32) for i in imgs], sim.camera.image_size, None, None)
    plain_err = K[[0, 1, 0, 1], [0, 1, 2, 2]] - truth
    cal = calibrate(sim.object_points, imgs, sim.camera.image_size)
    ours_err = cal.params[:4] - truth
    assert not cal.view_used[3] and cal.view_reasons[3].startswith("outlier")
    assert cal.view_used.sum() == 24
    assert np.all(np.abs(ours_err) < 0.35), ours_err
    assert abs(plain_err[3]) > 1.0  # plain calibrateCamera: cy off by more than a pixel
    assert np.max(np.abs(ours_err)) < 0.5 * np.max(np.abs(plain_err))


def test_single_corner_outliers_dropped():
    sim = _sim(7, 0.15, n_views=20)
    imgs = [i.copy() for i in sim.image_points]
    rng = np.random.default_rng(0)
    bad = [(v, int(rng.integers(0, BOARD.n_corners))) for v in range(0, 20, 2)]
    for v, c in bad:
        imgs[v][c] += [5.0, -4.0]
    cal = calibrate(sim.object_points, imgs, sim.camera.image_size)
    for v, c in bad:
        assert not cal.inliers[v][c]
    assert cal.view_used.all()
    assert cal.dropped_corners <= len(bad) + 3  # no mass rejection of good corners
    assert np.all(np.abs(cal.params[:4] - _truth(sim.camera)) < 0.5)


def test_fisheye_and_rational_models_recover_truth():
    from radarcal.camera import Camera

    cam = Camera((1280, 1024), np.array([[520.0, 0, 641.2], [0, 519.5, 508.7], [0, 0, 1]]), np.array([0.05, -0.02, 0.004, -0.001]), "fisheye")
    sim = simulate_views(cam, BOARD, 25, 0.15, np.random.default_rng(3), max_tilt_deg=45, fill=(0.35, 0.7), margin_px=3)
    cal = calibrate(sim.object_points, sim.image_points, cam.image_size, "fisheye")
    assert cal.camera.model == "fisheye"
    assert np.all(np.abs(cal.params[:4] - _truth(cam)) < 4 * np.array([cal.sigma[k] for k in KEYS]) + 0.05)
    cam8 = Camera((1280, 1024), np.array([[900.0, 0, 640.5], [0, 899.0, 512.3], [0, 0, 1]]), np.array([0.3, -0.05, 0.0, 0.0, 0.01, 0.6, 0.0, 0.02]))
    sim8 = simulate_views(cam8, BOARD, 25, 0.1, np.random.default_rng(4), max_tilt_deg=45, fill=(0.4, 0.9), margin_px=3)
    cal8 = calibrate(sim8.object_points, sim8.image_points, cam8.image_size, "pinhole8")
    # the rational model's coefficients are not identifiable individually; its projection is
    q = np.stack(np.meshgrid(np.linspace(50, 1230, 12), np.linspace(50, 970, 10)), -1).reshape(-1, 2)
    rays = cam8.unproject(q)
    uv, _ = cal8.camera.project(rays)
    assert np.median(np.linalg.norm(uv - q, axis=1)) < 0.3


def test_projection_uncertainty_map():
    sim = _sim(8, 0.1)
    cal = calibrate(sim.object_points, sim.image_points, sim.camera.image_size)
    um = projection_uncertainty(cal, nx=32)
    assert um.sigma_px.shape == (len(um.v), len(um.u)) == (26, 32)
    assert np.all(np.isfinite(um.sigma_px)) and np.all(um.sigma_px > 0)
    # lowest where the boards were (centre), highest at the corners of the image
    corners = um.sigma_px[[0, 0, -1, -1], [0, -1, 0, -1]]
    assert um.at_centre() < corners.min()
    # the mean-frames σ at the centre is below the raw σ(cx) (pose coupling absorbs a principal-point shift)
    assert um.at_centre() < cal.sigma["cx"]
    # empirical check: re-solve with fresh noise; project a world point fixed to the boards (mean over the true
    # board frames, at infinity) with each solution: its spread matches the predicted σ at that pixel
    from scipy.spatial.transform import Rotation

    cam = sim.camera
    q = np.array([[cam.cx + 200.0, cam.cy - 150.0]])
    p = cam.unproject(q)[0]
    R_true = np.array([T[:3, :3] for T in sim.T_cam_board])
    p_board = np.einsum("vji,j->vi", R_true, p)
    rng = np.random.default_rng(0)
    qs = []
    for _ in range(16):
        imgs = [t + rng.normal(scale=0.1, size=t.shape) for t in sim.image_points_true]
        cam2, rvecs2, _t, _rms = solve_once(sim.object_points, imgs, cam.image_size, "pinhole5", guess=cal.camera)
        p2 = np.einsum("vij,vj->vi", Rotation.from_rotvec(rvecs2).as_matrix(), p_board).mean(axis=0)
        qs.append(cam2.project(p2[None])[0][0])
    qs = np.array(qs)
    spread = np.sqrt(np.mean(np.sum((qs - qs.mean(axis=0)) ** 2, axis=1)))
    i, j = np.argmin(np.abs(um.v - q[0, 1])), np.argmin(np.abs(um.u - q[0, 0]))
    predicted = um.sigma_px[i, j]
    assert 0.4 * predicted < spread < 1.6 * np.sqrt(2) * predicted, (spread, predicted)
    assert um.valid.any()


@pytest.mark.slow
def test_mrcal_fisheye_corners_rational_model(shared):
    """Real wide-angle corners (Nikon D750 + Samyang 12 mm, 186 views, 6016x4016; SOURCE.md): the rational model
    with rejection lands nearer the published mrcal OPENCV8 solve (fx 2073.87, cx 3004.69) than plain
    calibrateCamera (fx 2070.72, cx 3002.92 per SOURCE.md)."""
    d = shared("mrcal_nikon_d750_samyang12mm_fisheye_corners")
    names, xy, w = [], [], []
    for line in (d / "corners.vnl").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        f, x, y, wt = line.split()
        names.append(f)
        xy.append([np.nan if x == "-" else float(x), np.nan if y == "-" else float(y)])
        w.append(np.nan if wt == "-" else float(wt))
    names, xy, w = np.array(names), np.array(xy), np.array(w)
    grid = np.array([[(i % 10) * 0.077, (i // 10) * 0.077, 0.0] for i in range(100)])
    obj, img = [], []
    for n in dict.fromkeys(names):
        sel = np.flatnonzero(names == n)
        ok = np.isfinite(xy[sel, 0]) & (w[sel] > 0)
        if ok.sum() >= 20:
            obj.append(grid[ok])
            img.append(xy[sel][ok])
    assert len(obj) == 186
    cal = calibrate(obj, img, (6016, 4016), "pinhole8")
    assert abs(cal.camera.fx - 2073.87) < 2.0 and abs(cal.camera.fx - 2073.87) < abs(2070.72 - 2073.87)
    assert abs(cal.camera.cx - 3004.69) < 2.0 and abs(cal.camera.cy - 1997.38) < 2.0
    assert cal.rms_px < 1.364  # plain OpenCV rational: 1.364 px
    assert cal.iterations < 15  # converged
    assert 0 < cal.dropped_corners < 0.06 * sum(len(o) for o in obj)  # mrcal 2.2 drops 2.1 % (own model/regularisation)


@pytest.mark.parametrize("n_points", [4, 5, 6, 54])
def test_board_pose_with_few_corners(n_points):
    """OpenCV 5's SOLVEPNP_ITERATIVE asserts below 6 points; board_pose must still recover a known pose."""
    from radarcal.board import BoardSpec, object_points
    from radarcal.camera import Camera
    from radarcal.geometry import T_from_xyz_rpy_deg, pose_error, T_from_rotvec
    from radarcal.intrinsics.solve import board_pose

    cam = Camera((1280, 1024), [[1000.0, 0, 640], [0, 1000.0, 512], [0, 0, 1]], [-0.1, 0.05, 0.001, -0.001, 0.0])
    obj = object_points(BoardSpec("chessboard", 9, 6, 0.025))
    idx = np.array([0, 8, 45, 53, 22, 31])[:n_points] if n_points <= 6 else np.arange(len(obj))  # board corners first
    T_cam_board = T_from_xyz_rpy_deg(-0.1, 0.05, 0.8, 20, -15, 5)
    uv, valid, _ = cam.project_from(T_cam_board, obj[idx])
    assert valid.all()
    rv, tv = board_pose(cam, obj[idx], uv)
    rot_deg, trans_m = pose_error(T_from_rotvec(rv, tv), T_cam_board)
    assert rot_deg < 1e-6 and trans_m < 1e-8

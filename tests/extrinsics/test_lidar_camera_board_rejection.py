"""Issue #16 item 4: a board whose corners disagree is rejected as a whole, the sigma covers board-level errors,
and a pose whose residuals say it is wrong is not stored without --force."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import Bundle, load_bundle, save_bundle
from radarcal.cli.main import main
from radarcal.extrinsics.lidar_camera import solve_corners
from radarcal.synth.lidar_camera import default_camera, default_T_cam_lidar


def _boards(rng, T, cam, n=6, offset_m=0.0):
    """Corners (n*4, 3) of 1.0 x 0.8 m boards 4-9 m in front of the LiDAR, their pixels, and board labels."""
    P = []
    for k in range(n):
        c = np.array([rng.uniform(4, 9), rng.uniform(-2.5, 2.5), rng.uniform(-0.5, 1.0)])
        yaw = rng.uniform(-0.5, 0.5)
        u = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        half = np.array([[-0.5, -0.4], [0.5, -0.4], [0.5, 0.4], [-0.5, 0.4]])
        P.append(c + half[:, :1] * u + half[:, 1:] * [0, 0, 1])
    P = np.vstack(P)
    uv, ok, _ = cam.project_from(T, P)
    assert ok.all()
    return P, uv, np.repeat(np.arange(n), 4)


def test_a_board_with_disagreeing_corners_is_rejected_whole():
    rng = np.random.default_rng(5)
    cam = default_camera()
    T = default_T_cam_lidar(rng)
    P, uv, g = _boards(rng, T, cam)
    uv = uv + rng.normal(0, 0.7, uv.shape)
    # board 2: the image corners of a wrongly found chessboard, each off by a different amount (4-45 px):
    # per-corner 3-sigma rejection keeps the two least wrong ones and biases the pose
    uv[8:12] += np.array([[4.0, -1.5], [35.0, 20.0], [-30.0, 25.0], [3.0, 3.5]])
    sol = solve_corners(cam, P, uv, groups=g)
    assert sol.outliers[8:12].all() and sol.outliers.sum() == 4 and sol.ok
    deg, m = geometry.pose_error(sol.T_cam_lidar, T)
    assert deg < 0.15 and m < 0.03, (deg, m)


def test_board_jackknife_sigma_covers_a_biased_cloud_board():
    # every board's cloud rectangle is shifted by its own ~2 cm (what a rectangle fit on a noisy sparse patch gives):
    # the pixel residuals stay small, but the pose is off by more than the pixel-noise sigma says
    cover = []
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        cam = default_camera()
        T = default_T_cam_lidar(rng)
        P, uv, g = _boards(rng, T, cam, n=5)
        P = P + np.repeat(rng.normal(0, 0.02, (5, 3)), 4, axis=0)
        sol = solve_corners(cam, P, uv + rng.normal(0, 0.5, uv.shape), groups=g)
        d = sol.T_cam_lidar @ geometry.invert_T(T)
        err = np.r_[geometry.R_to_rotvec(d[:3, :3]), d[:3, 3]]
        cover.append(np.abs(err) < 3 * sol.sigma)
    # 3 sigma should cover ~99 % per axis: measured 88 % with the board jackknife, 67 % with the pixel-noise sigma alone
    assert np.mean(cover) > 0.85, np.mean(cover, axis=0)


@pytest.fixture
def corner_bundle(tmp_path):
    cam = default_camera()
    b = Bundle()
    b.set_camera("cam0", cam)
    path = tmp_path / "b.yaml"
    save_bundle(b, path)
    rng = np.random.default_rng(9)
    T = default_T_cam_lidar(rng)
    p = np.column_stack([rng.uniform(4, 12, 30), rng.uniform(-3, 3, 30), rng.uniform(-1, 2, 30)])
    uv, _, _ = cam.project_from(T, p)
    return path, p, uv, rng


def _write_corners(path, p, uv):
    path.write_text("x,y,z,u,v\n" + "".join(f"{a:.9g},{b:.9g},{c:.9g},{u:.6f},{v:.6f}\n" for (a, b, c), (u, v) in zip(p, uv)))
    return path


def test_residuals_that_say_wrong_are_not_stored_without_force(corner_bundle, tmp_path, capsys):
    path, p, uv, rng = corner_bundle
    before = path.read_bytes()
    # picks matched to the wrong points: every pixel 6-10 px off in a random direction (no single outlier to drop)
    ang = rng.uniform(0, 2 * np.pi, len(uv))
    bad = _write_corners(tmp_path / "c.csv", p, uv + rng.uniform(6, 10, len(uv))[:, None] * np.column_stack([np.cos(ang), np.sin(ang)]))
    assert main(["lidar-camera", "-b", str(path), "--corners", str(bad), "--json"]) == 1
    s = json.loads(capsys.readouterr().out)
    assert not s["stored"] and any("reprojection RMS" in r for r in s["refused"])
    assert path.read_bytes() == before and not (tmp_path / "b.sessions").exists()
    assert main(["lidar-camera", "-b", str(path), "--corners", str(bad), "--force", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stored"] and "T_cam0_lidar0" in load_bundle(path).transforms
    good = _write_corners(tmp_path / "g.csv", p, uv + rng.normal(0, 0.5, uv.shape))
    assert main(["lidar-camera", "-b", str(path), "--corners", str(good), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["pnp"]["ok"]


@pytest.mark.parametrize("rows", ["collinear", "duplicated"])
def test_degenerate_corner_rows_are_input_errors(corner_bundle, tmp_path, capsys, rows):
    path, p, uv, _ = corner_bundle
    if rows == "collinear":
        t = np.linspace(0, 1, 8)[:, None]
        q = np.array([5.0, -1, 0]) + t * [1.0, 2.0, 0.5]
        f = _write_corners(tmp_path / "c.csv", q, 300 + t * [200.0, 100.0])
    else:
        f = _write_corners(tmp_path / "c.csv", np.repeat(p[:2], 4, axis=0), np.repeat(uv[:2], 4, axis=0))
    before = path.read_bytes()
    assert main(["lidar-camera", "-b", str(path), "--corners", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {f}: ") and err.count("\n") == 1 and ("collinear" in err or "duplicated" in err), err
    assert path.read_bytes() == before


@pytest.mark.slow
def test_issue_scene_seed3_six_boards(tmp_path, capsys):
    """The issue's command: `synth lidar-camera --seed 3 --boards 6`, `lidar-camera --board 1.0,0.8 --board-squares 5,4`
    stored 1.75 deg / 13.9 cm from the truth with sigma 0.18 deg / 1.3 cm (two far boards with wrong image corners)."""
    S = tmp_path / "S"
    assert main(["synth", "lidar-camera", "-o", str(S), "--seed", "3", "--boards", "6", "--duration", "2"]) == 0
    capsys.readouterr()
    assert main(["lidar-camera", "-b", str(S / "bundle.yaml"), "--image", str(S / "image.png"), "--cloud", str(S / "cloud.pcd"),
                 "--board", "1.0,0.8", "--board-squares", "5,4", "--json"]) == 0  # fmt: skip
    s = json.loads(capsys.readouterr().out)
    T_true = np.array(json.loads((S / "truth.json").read_text())["T_cam_lidar"])
    T = np.asarray(s["T_cam_lidar"])
    d = T @ geometry.invert_T(T_true)
    err = np.abs(np.r_[np.degrees(geometry.R_to_rotvec(d[:3, :3])), d[:3, 3]])
    sig = np.r_[s["pnp"]["sigma_rot_deg"], s["pnp"]["sigma_trans_m"]]
    deg, m = geometry.pose_error(T, T_true)
    assert deg < 0.7 and m < 0.06, (deg, m)  # measured 0.47 deg / 4.1 cm (was 1.75 deg / 13.9 cm)
    assert np.all(err < 3 * sig), (err, sig)  # measured err/sigma <= 0.9 on every axis (was ~10)
    assert len(s["pnp"]["flagged_rows"]) == 8  # the two bad boards, all their corners

"""radarcal synth board: the renderer against geometry (detected corners vs truth projection), the set writer, the CLI."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from radarcal.camera import Camera
from radarcal.errors import InputError
from radarcal.io import read_image
from radarcal.synth.board import (
    BoardRenderer,
    BoardSpec,
    RenderSettings,
    board_object_points,
    board_truth_pixels,
    bow_warp,
    default_camera,
    load_board_truth,
    plan_views,
    write_board_set,
)

CHESS = BoardSpec("chessboard", 9, 6, 0.025)
SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)


def _match_order(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Detectors may return a chessboard 180 deg rotated (reverse order): align to the truth order."""
    if np.linalg.norm(found[0] - truth[0]) > np.linalg.norm(found[0] - truth[-1]):
        return found[::-1]
    return found


def _detect_chessboard(img: np.ndarray, spec: BoardSpec) -> np.ndarray | None:
    """findChessboardCorners + cornerSubPix with a half-window of 0.4 x the smallest neighbouring-corner gap."""
    ok, c = cv2.findChessboardCorners(img, (spec.cols, spec.rows), flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    c = c.reshape(-1, 2)
    grid = c.reshape(spec.rows, spec.cols, 2)
    gap = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(), np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    hw = max(2, int(0.4 * gap))
    return cv2.cornerSubPix(img, c.reshape(-1, 1, 2).astype(np.float32).copy(), (hw, hw), (-1, -1), SUBPIX).reshape(-1, 2)


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _polygon_area_centroid(p: np.ndarray) -> tuple[float, np.ndarray]:
    x, y = p[:, 0], p[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    c = x * y1 - x1 * y
    a = c.sum() / 2
    return abs(a), np.array([((x + x1) * c).sum(), ((y + y1) * c).sum()]) / (6 * a)


# --- geometry conventions ------------------------------------------------------------------------------------------
def test_object_points_follow_opencv_order():
    cb = BoardSpec("charuco", 5, 7, 0.04, 0.03, "DICT_5X5_100")
    np.testing.assert_allclose(board_object_points(cb), cb.cv_board().getChessboardCorners(), atol=1e-12)
    # chessboard: an upright frontal render is returned by findChessboardCorners in board_object_points order
    cam = Camera((640, 480), [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]], np.zeros(5))
    T = np.eye(4)
    T[:3, 3] = [-CHESS.centre[0], -CHESS.centre[1], 0.5]
    img = BoardRenderer(cam, CHESS, RenderSettings(noise_sigma=0)).render(T, np.random.default_rng(0))
    ok, c = cv2.findChessboardCorners(img, (9, 6))
    assert ok
    uv, vis = board_truth_pixels(cam, CHESS, T)
    assert vis.all()
    np.testing.assert_allclose(c.reshape(-1, 2), uv, atol=0.3)
    # the first corner is 0.1 m left of and 0.0625 m above the squares' centre: at 0.5 m and f = 500 px, 100 / 62.5 px
    np.testing.assert_allclose(uv[0], [319.5 - 100, 239.5 - 62.5], atol=1e-9)


@pytest.mark.parametrize("model", ["pinhole5", "fisheye"])
def test_paper_area_and_centroid_match_projection(model):
    """Renderer exactness without any detector: the rendered paper coverage integrates to the projected outline."""
    cam = default_camera(model, (640, 480))
    views = plan_views(cam, CHESS, 2, np.random.default_rng(3), n_partial=0)
    r = BoardRenderer(cam, CHESS, RenderSettings(supersample=6))
    x0, y0, x1, y1 = CHESS.squares_extent
    m = CHESS.paper_margin
    X0, Y0, X1, Y1 = x0 - m, y0 - m, x1 + m, y1 + m
    t = np.linspace(0, 1, 2000, endpoint=False)
    outline = np.concatenate([np.stack([X0 + (X1 - X0) * t, Y0 + 0 * t], 1), np.stack([X1 + 0 * t, Y0 + (Y1 - Y0) * t], 1),
                              np.stack([X1 - (X1 - X0) * t, Y1 + 0 * t], 1), np.stack([X0 + 0 * t, Y1 - (Y1 - Y0) * t], 1)])
    u, v = np.meshgrid(np.arange(640.0), np.arange(480.0))
    checked = 0
    for view in views:
        uv, ok, _ = cam.project_from(view.T_cam_board, np.c_[outline, np.zeros(len(outline))])
        if not (ok.all() and cam.in_image(uv, 2.0).all()):
            continue  # the paper must be wholly inside the image for the integral to be comparable
        area, centroid = _polygon_area_centroid(uv)
        _, frac = r.coverage(view.T_cam_board)
        a = float(frac.sum())
        c = np.array([(frac * u).sum(), (frac * v).sum()]) / a
        assert abs(a - area) < 2e-4 * area + 1.0
        assert np.abs(c - centroid).max() < 0.01
        checked += 1
    assert checked >= 1


# --- detected corners vs truth ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("model,size", [("pinhole5", (1280, 1024)), ("pinhole5", (640, 480)), ("pinhole8", (640, 480))])
def test_chessboard_corners_subpixel(model, size):
    cam = default_camera(model, size)
    rng = np.random.default_rng(7)
    views = plan_views(cam, CHESS, 4, rng, n_partial=0)
    r = BoardRenderer(cam, CHESS, RenderSettings(noise_sigma=0.5, blur_sigma=0.6))
    errors = []
    for view in views:
        img = r.render(view.T_cam_board, rng, gain=view.gain)
        uv, vis = board_truth_pixels(cam, CHESS, view.T_cam_board)
        assert vis.all()
        found = _detect_chessboard(img, CHESS)
        assert found is not None
        errors.append(_match_order(found, uv) - uv)
    e = np.concatenate(errors)
    rms = float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
    assert rms < 0.1, rms
    assert np.abs(e.mean(axis=0)).max() < 0.02  # no half-pixel convention slip


@pytest.mark.parametrize("legacy", [False, True])
def test_charuco_layouts_detect_only_with_the_right_flag(legacy):
    spec = BoardSpec("charuco", 8, 8, 0.03, 0.022, "DICT_4X4_1000", legacy=legacy)  # even rows: layouts differ
    cam = default_camera("pinhole5", (640, 480))
    rng = np.random.default_rng(11)
    views = plan_views(cam, spec, 2, rng, n_partial=0)
    r = BoardRenderer(cam, spec, RenderSettings(noise_sigma=0.5))
    counts = {False: 0, True: 0}
    errors = []
    for view in views:
        img = r.render(view.T_cam_board, rng)
        uv, _ = board_truth_pixels(cam, spec, view.T_cam_board)
        for flag in (False, True):
            board = spec.cv_board()
            board.setLegacyPattern(flag)
            corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(img)
            n = 0 if ids is None else len(ids)
            counts[flag] += n
            if flag == legacy and n:
                errors.append(corners.reshape(-1, 2) - uv[ids.ravel()])
    assert counts[not legacy] == 0
    assert counts[legacy] >= 0.8 * 2 * spec.n_corners
    assert _rms(np.concatenate(errors), 0 * np.concatenate(errors)) < 0.15


def test_ray_grids_agree_with_camera_project():
    from radarcal.synth.board_render import _ray_grid

    for model in ("pinhole8", "fisheye"):
        cam = default_camera(model, (320, 256))
        g = _ray_grid(cam, 190.0)
        rays = g.rays.reshape(-1, 3)
        u, v = np.meshgrid(np.arange(320.0), np.arange(256.0))
        uv = np.stack([u.ravel(), v.ravel()], axis=1)
        norm = np.maximum(np.linalg.norm(rays, axis=1), 1e-300)
        front = g.valid.ravel() & (rays[:, 2] / norm > np.cos(np.radians(89.5)))
        back, ok = cam.project(rays[front])
        assert ok.all() and np.abs(back - uv[front]).max() < 1e-6
        if model == "fisheye":  # the 190 deg image circle is fully usable, including the rays behind the camera
            inside = g.lens > 0
            assert g.valid[inside].all() and (rays[inside.ravel(), 2] < 0).any()
        else:
            assert g.valid.all()


def test_fisheye_corners_match_truth():
    cam = default_camera("fisheye", (1280, 1024))
    rng = np.random.default_rng(5)
    views = plan_views(cam, CHESS, 3, rng, n_partial=0)
    r = BoardRenderer(cam, CHESS, RenderSettings(noise_sigma=0.5))
    errors = []
    for view in views:
        img = r.render(view.T_cam_board, rng)
        uv, _ = board_truth_pixels(cam, CHESS, view.T_cam_board)
        found = _detect_chessboard(img, CHESS)
        assert found is not None
        errors.append(_match_order(found, uv) - uv)
    e = np.concatenate(errors)
    # measured 0.046-0.051 px over seeds 5-7 (edges are curved within the window, still well inside 0.1 px)
    assert _rms(e, 0 * e) < 0.1


def test_bad_view_is_displaced_as_recorded():
    cam = default_camera("pinhole5", (640, 480))
    rng = np.random.default_rng(2)
    (view,) = plan_views(cam, CHESS, 1, rng, n_partial=0)
    from radarcal.synth.board import bad_view_amplitude

    amp = bad_view_amplitude(cam, CHESS, view.T_cam_board, 2.0)
    warp = bow_warp(CHESS, amp)
    uv, _ = board_truth_pixels(cam, CHESS, view.T_cam_board)
    uv_bad, _ = board_truth_pixels(cam, CHESS, view.T_cam_board, warp=warp)
    assert abs(np.linalg.norm(uv_bad - uv, axis=1).max() - 2.0) < 0.01
    img = BoardRenderer(cam, CHESS, RenderSettings(noise_sigma=0.3)).render(view.T_cam_board, rng, warp=warp)
    found = _match_order(_detect_chessboard(img, CHESS), uv)
    assert _rms(found, uv_bad) < 0.1 < 0.5 < _rms(found, uv)


def test_view_planner_coverage_full_vs_poor():
    cam = default_camera("pinhole5", (1280, 1024))
    pts = {}
    for coverage in ("full", "poor"):
        views = plan_views(cam, CHESS, 25, np.random.default_rng(0), coverage=coverage, n_partial=0)
        uv = np.concatenate([board_truth_pixels(cam, CHESS, v.T_cam_board)[0] for v in views])
        pts[coverage] = uv / cam.image_size
        tilts = [np.degrees(np.arccos(v.T_cam_board[:3, 2] @ (v.T_cam_board[:3, 3] / np.linalg.norm(v.T_cam_board[:3, 3])))) for v in views]
        if coverage == "full":
            assert max(tilts) > 35  # strongly tilted views are present
    full, poor = pts["full"], pts["poor"]
    # full: corners reach every image quadrant and near all four borders; poor: only the upper-left part
    assert full.min(axis=0).max() < 0.12 and full.max(axis=0).min() > 0.88
    assert poor.max(axis=0).max() < 0.62
    hist_full = np.histogram2d(full[:, 0], full[:, 1], bins=4, range=[[0, 1], [0, 1]])[0]
    assert (hist_full > 0).all()


# --- the set writer ----------------------------------------------------------------------------------------------------
def _small_set(path, seed=3, **kw):
    args = dict(n_views=5, seed=seed, n_partial=1, n_blank=1, n_corrupt=1, bad_view=True, n_blurred=1)
    args.update(kw)
    return write_board_set(path, default_camera("pinhole5", (640, 480)), CHESS, settings=RenderSettings(noise_sigma=1.0), **args)


def test_set_is_deterministic(tmp_path):
    _small_set(tmp_path / "a")
    _small_set(tmp_path / "b")
    _small_set(tmp_path / "c", seed=4)
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "b").iterdir())
    for n in names:
        assert (tmp_path / "a" / n).read_bytes() == (tmp_path / "b" / n).read_bytes(), n
    assert (tmp_path / "a" / "truth.json").read_bytes() != (tmp_path / "c" / "truth.json").read_bytes()


def test_truth_json_consistent_with_files(tmp_path):
    (tmp_path / "img_042.png").write_bytes(b"stale")  # a file of an earlier, bigger set in the same folder
    (tmp_path / "truth.json").write_text("{}")
    _small_set(tmp_path)
    loaded = load_board_truth(tmp_path)
    truth = loaded.raw
    assert loaded.spec == CHESS and [p.name for p in loaded.files("blank")] == truth["files"]["blank"]
    cam = Camera.from_dict(truth["camera"])
    spec = BoardSpec.from_dict(truth["board"])
    obj = np.asarray(truth["object_points"])
    np.testing.assert_allclose(obj, board_object_points(spec))
    files = truth["files"]
    assert len(files["all"]) == 5 + 1 + 1 == len(truth["views"])
    assert [len(files[k]) for k in ("full", "partial", "bad", "blurred", "blank", "corrupt")] == [2, 1, 1, 1, 1, 1]
    sharpness = {}
    assert sorted(p.name for p in tmp_path.glob("*.png")) == sorted(files["all"])
    for v in truth["views"]:
        path = tmp_path / v["file"]
        if v["kind"] == "corrupt":
            assert not v["readable"]
            with pytest.raises(InputError):
                read_image(path)
            continue
        img = read_image(path, grayscale=True)
        assert img.shape == (480, 640)
        if v["kind"] == "blank":
            assert v["T_cam_board"] is None and not v["has_board"]
            assert not cv2.findChessboardCorners(img, (9, 6))[0]
            continue
        T = np.asarray(v["T_cam_board"])
        uv_true, ok, _ = cam.project_from(T, obj)
        uv = np.array([[np.nan if x is None else x for x in row] for row in v["corners_uv"]], float)
        np.testing.assert_allclose(uv[ok], uv_true[ok], atol=1e-5)
        vis = np.asarray(v["visible"])
        np.testing.assert_array_equal(vis, ok & cam.in_image(uv_true))
        assert v["corner_ids"] == np.nonzero(vis)[0].tolist() and v["n_visible"] == int(vis.sum())
        if v["kind"] == "partial":
            assert 0.3 <= vis.mean() <= 0.8
        else:
            assert vis.all()
            sharpness.setdefault(v["kind"], []).append(cv2.Laplacian(img, cv2.CV_64F).var())
            if v["kind"] == "blurred":  # smeared by a symmetric streak (6.4-10.2 px at 640 px width): not shifted
                assert 6.4 <= v["motion_blur_px"] <= 10.3
                ok, found = cv2.findChessboardCornersSB(img, (9, 6))
                assert not ok or np.abs(np.mean(_match_order(found.reshape(-1, 2), uv) - uv, axis=0)).max() < 0.3
                continue
            found = _detect_chessboard(img, spec)
            assert found is not None
            target = np.asarray(v["corners_uv_actual"]) if v["kind"] == "bad" else uv
            assert _rms(_match_order(found, uv), target) < 0.1
    assert max(sharpness["blurred"]) < 0.5 * min(sharpness["full"])


def test_cli_writes_a_set_and_rejects_bad_input(tmp_path, capsys):
    from radarcal.cli.main import main

    out = tmp_path / "set"
    code = main(["synth", "board", str(out), "--board", "charuco", "--cols", "5", "--rows", "4", "--square", "0.04",
                 "--marker", "0.03", "--layout", "legacy", "--image-size", "640x480", "--views", "2", "--partial", "0", "--blank", "1",
                 "--corrupt", "0", "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_files"] == 3 and summary["board"]["legacy"] is True
    truth = json.loads((out / "truth.json").read_text())
    assert truth["board"]["type"] == "charuco" and len(truth["views"]) == 3
    assert main(["synth", "board", str(tmp_path / "x"), "--image-size", "big"]) == 2
    assert main(["synth", "board", str(tmp_path / "x"), "--board", "charuco", "--marker", "0.05"]) == 2
    assert main(["synth", "board", str(tmp_path / "x"), "--cols", "30", "--rows", "20", "--image-size", "320x240"]) == 2
    assert "error: --" in capsys.readouterr().err


def test_committed_sample_regenerates_bit_for_bit(tmp_path):
    """datasets/synth_board_640 (made by datasets/regenerate_synth_board.sh) comes back byte-identical from its seed."""
    from pathlib import Path

    sample = Path(__file__).resolve().parents[2] / "datasets" / "synth_board_640"
    if not (sample / "truth.json").is_file():
        pytest.skip("datasets/synth_board_640 not present")
    truth = json.loads((sample / "truth.json").read_text())
    write_board_set(tmp_path, Camera.from_dict(truth["camera"]), BoardSpec.from_dict(truth["board"]), n_views=6, seed=0,
                    settings=RenderSettings(noise_sigma=1.0, blur_sigma=0.6), n_partial=1, n_blank=1, n_corrupt=1, bad_view=True,
                    command=truth["command"])
    for name in truth["files"]["all"] + ["truth.json"]:
        assert (tmp_path / name).read_bytes() == (sample / name).read_bytes(), name


def test_stereo_set_recovers_the_true_baseline(tmp_path):
    """Both cameras' renders are consistent: stereoCalibrate (true intrinsics fixed) on detected corners finds T_cam1_cam0."""
    from radarcal.geometry import pose_error
    from radarcal.synth.board import default_stereo_camera

    cam0 = default_camera("pinhole5", (640, 480))
    rig = default_stereo_camera(cam0, 0.12)
    truth = write_board_set(tmp_path, cam0, CHESS, n_views=6, seed=1, n_partial=0, n_blank=1, n_corrupt=0, stereo=rig)
    loaded = load_board_truth(tmp_path)
    st = truth["stereo"]
    cam1 = Camera.from_dict(st["camera1"])
    T10 = np.asarray(st["T_cam1_cam0"])
    assert abs(st["baseline_m"] - 0.12) < 1e-9 and len(st["files1"]["full"]) == 6
    obj = board_object_points(CHESS).astype(np.float32)
    p0, p1 = [], []
    for v in loaded.views:
        if v["kind"] != "full":
            assert v["file"].startswith("cam0/") and v["file_cam1"].startswith("cam1/") and v["T_cam1_board"] is None
            continue
        np.testing.assert_allclose(np.asarray(v["T_cam1_board"]), T10 @ v["T"], atol=1e-9)
        uv1 = np.array(v["corners_uv_cam1"], float)
        np.testing.assert_allclose(uv1, cam1.project_from(T10 @ v["T"], obj)[0], atol=1e-5)
        f0 = _detect_chessboard(read_image(tmp_path / v["file"], grayscale=True), CHESS)
        f1 = _detect_chessboard(read_image(tmp_path / v["file_cam1"], grayscale=True), CHESS)
        p0.append(_match_order(f0, v["uv"]).astype(np.float32))
        p1.append(_match_order(f1, uv1).astype(np.float32))
        assert _rms(p1[-1], uv1) < 0.1
    out = cv2.stereoCalibrate([obj] * len(p0), p0, p1, cam0.K, cam0.dist, cam1.K, cam1.dist, cam0.image_size,
                              flags=cv2.CALIB_FIX_INTRINSIC)
    T_est = np.eye(4)
    T_est[:3, :3], T_est[:3, 3] = out[5], out[6].ravel()
    deg, m = pose_error(T_est, T10)
    print(f"stereo: rotation error {deg:.4f} deg, translation error {m * 1000:.3f} mm")
    assert deg < 0.02 and m < 0.3e-3, (deg, m)


def test_video_follows_the_recorded_trajectory(tmp_path):
    cam = default_camera("pinhole5", (640, 480))
    kw = dict(n_views=3, seed=2, n_partial=0, n_blank=0, n_corrupt=0, video_seconds=2.0, video_fps=10.0)
    truth = write_board_set(tmp_path / "a", cam, CHESS, **kw)
    write_board_set(tmp_path / "b", cam, CHESS, **kw)
    assert (tmp_path / "a" / "video.avi").read_bytes() == (tmp_path / "b" / "video.avi").read_bytes()
    vd = truth["video"]
    cap = cv2.VideoCapture(str(tmp_path / "a" / "video.avi"))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY))
    assert len(frames) == vd["n_frames"] == 21 and vd["keyframes"] == [0, 10, 20]  # key poses land on frames
    # the key poses are the set's full views; the board rests there and moves (blurred) in between
    by_file = {v["file"]: v for v in truth["views"]}
    assert len(vd["keyframe_files"]) == 3 and all(by_file[f]["kind"] == "full" for f in vd["keyframe_files"])
    for k, f in zip(vd["keyframes"], vd["keyframe_files"]):
        v = by_file[f]
        np.testing.assert_allclose(vd["frames"][k]["T_cam_board"], v["T_cam_board"], atol=1e-9)
        assert vd["frames"][k]["motion_blur_px"] == 0.0
    assert max(f["motion_blur_px"] for f in vd["frames"]) > 3.0
    for k in vd["keyframes"]:
        uv, _ = board_truth_pixels(cam, CHESS, np.asarray(vd["frames"][k]["T_cam_board"]))
        found = _detect_chessboard(frames[k], CHESS)
        assert found is not None and _rms(_match_order(found, uv), uv) < 0.15  # MJPG-compressed

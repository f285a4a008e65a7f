"""``radarcal intrinsics`` end to end on sets rendered by ``radarcal synth board`` (known truth in truth.json):
bad/blurred/blank/corrupt files named, wrong board size diagnosed, accuracy against the true camera."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle
from radarcal.cli.main import main
from radarcal.synth import load_board_truth


def _synth(out, *args):
    assert main(["synth", "board", str(out), *args]) == 0


def _intrinsics(capsys, *args):
    capsys.readouterr()  # drop what `synth board` printed
    code = main(["intrinsics", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def chess_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("chess640")
    _synth(out, "--image-size", "640x480", "--views", "14", "--bad-view", "--blurred", "1", "--blank", "2", "--corrupt", "1", "--seed", "2")
    return out


def _kinds(truth_dir):
    t = json.loads((truth_dir / "truth.json").read_text())
    return {v["file"]: v["kind"] for v in t["views"]}


def test_rendered_chessboard_every_bad_file_named(chess_set, tmp_path, capsys):
    code, out, err = _intrinsics(capsys, str(chess_set), "--cols", "9", "--rows", "6", "--square", "0.025", "--bundle", str(tmp_path / "b.yaml"), "--json")
    assert code == 0, err
    s = json.loads(out)["cameras"][0]
    kinds = _kinds(chess_set)
    rejected = {k.rsplit("/", 1)[-1]: v for k, v in s["rejected"].items()}
    for f, kind in kinds.items():
        if kind == "full":
            assert f not in rejected, (f, rejected.get(f))
        elif kind == "blank":
            assert rejected[f] == "no board"
        elif kind == "corrupt":
            assert rejected[f].startswith("unreadable")
        elif kind == "bad":
            assert rejected[f].startswith("outlier")
        elif kind == "blurred":
            assert rejected[f].startswith("blurred")
        elif kind == "partial":  # a chessboard must be seen whole
            assert rejected[f] == "no board"
    truth = load_board_truth(chess_set)
    K = np.asarray(s["K"])
    est = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    true = np.array([truth.camera.fx, truth.camera.fy, truth.camera.cx, truth.camera.cy])
    sig = np.array([s["sigma"][k] for k in ("fx", "fy", "cx", "cy")])
    assert np.all(np.abs(est - true) < 3 * sig + 0.05), (est - true, sig)
    assert np.all(np.abs(est - true) < 0.6)
    assert s["rms_px"] < 0.1  # rendered corners: ~0.04 px


def test_rendered_wrong_size_named(chess_set, tmp_path, capsys):
    code, _out, err = _intrinsics(capsys, str(chess_set), "--cols", "9", "--rows", "7", "--square", "0.025", "--bundle", str(tmp_path / "b.yaml"))
    assert code == 2 and "no 9x7 chessboard found" in err and "a 9x6 chessboard" in err


def test_rendered_blank_only_folder(tmp_path, capsys):
    out = tmp_path / "blank"
    _synth(out, "--image-size", "320x240", "--views", "3", "--partial", "0", "--blank", "3", "--corrupt", "1", "--seed", "4")
    t = json.loads((out / "truth.json").read_text())
    for v in t["views"]:  # keep only the blank frames and the corrupt file
        if v["kind"] not in ("blank", "corrupt"):
            (out / v["file"]).unlink()
    code, _o, err = _intrinsics(capsys, str(out), "--cols", "9", "--rows", "6", "--square", "0.025", "--bundle", str(tmp_path / "b.yaml"))
    assert code == 2 and err.startswith("error: ") and "no 9x6 chessboard found in any of 4 inputs" in err
    assert "Traceback" not in err


def test_rendered_charuco_legacy_auto(tmp_path, capsys):
    out = tmp_path / "charuco"
    _synth(out, "--board", "charuco", "--cols", "8", "--rows", "6", "--square", "0.03", "--marker", "0.022", "--dict", "DICT_4X4_1000", "--layout", "legacy", "--image-size", "640x480", "--views", "10", "--blank", "0", "--corrupt", "0", "--seed", "3")
    code, o, err = _intrinsics(capsys, str(out), "--board", "charuco", "--cols", "8", "--rows", "6", "--square", "0.03", "--marker", "0.022", "--bundle", str(tmp_path / "b.yaml"), "--json", "--no-crossval")
    assert code == 0, err
    s = json.loads(o)["cameras"][0]
    assert s["charuco_layout"]["legacy"] is True and s["charuco_layout"]["corners_new_layout"] == 0
    truth = load_board_truth(out)
    K = np.asarray(s["K"])
    sig = s["sigma"]
    assert abs(K[0, 0] - truth.camera.fx) < 3 * sig["fx"] + 0.05
    assert abs(K[0, 2] - truth.camera.cx) < 3 * sig["cx"] + 0.05
    assert s["views_used"] == 10  # the partial view counts: ChArUco corners are identified individually


def test_rendered_stereo_recovers_T(tmp_path, capsys):
    out = tmp_path / "stereo"
    _synth(out, "--image-size", "640x480", "--views", "10", "--partial", "0", "--blank", "0", "--corrupt", "0", "--stereo-baseline", "0.12", "--seed", "5")
    code, o, err = _intrinsics(capsys, str(out / "cam0"), "--cols", "9", "--rows", "6", "--square", "0.025", "--right", str(out / "cam1"), "--bundle", str(tmp_path / "b.yaml"), "--json", "--no-crossval")
    assert code == 0, err
    t = json.loads((out / "truth.json").read_text())
    T_true = np.asarray(t["stereo"]["T_cam1_cam0"])
    T = load_bundle(tmp_path / "b.yaml").T("cam1", "cam0")
    deg, m = geometry.pose_error(T, T_true)
    s = json.loads(o)["stereo"]
    assert m < 3 * s["sigma"]["baseline_m"] + 3e-4 and deg < 0.05
    assert abs(s["baseline_m"] - t["stereo"]["baseline_m"]) < 3e-4


@pytest.mark.slow
def test_rendered_1280x1024_accuracy(tmp_path, capsys):
    """25 rendered 1280x1024 views + partial/bad/blurred/blank/corrupt: |Δfx|,|Δfy|,|Δcx|,|Δcy| < 0.3 px."""
    out = tmp_path / "big"
    _synth(out, "--image-size", "1280x1024", "--views", "25", "--bad-view", "--blurred", "1", "--seed", "11")
    code, o, err = _intrinsics(capsys, str(out), "--cols", "9", "--rows", "6", "--square", "0.025", "--bundle", str(tmp_path / "b.yaml"), "--json")
    assert code == 0, err
    s = json.loads(o)["cameras"][0]
    truth = load_board_truth(out)
    K = np.asarray(s["K"])
    err_px = np.array([K[0, 0] - truth.camera.fx, K[1, 1] - truth.camera.fy, K[0, 2] - truth.camera.cx, K[1, 2] - truth.camera.cy])
    assert np.all(np.abs(err_px) < 0.3), err_px
    kinds = _kinds(out)
    rejected = {k.rsplit("/", 1)[-1]: v for k, v in s["rejected"].items()}
    assert all(rejected[f].startswith("outlier") for f, k in kinds.items() if k == "bad")


def test_rendered_fisheye_auto_model(tmp_path, capsys):
    """A 190° equidistant lens (OpenCV's own fisheye start diverges here): --model auto picks fisheye and
    recovers the truth; pinhole5 is rejected by its RMS."""
    out = tmp_path / "fish"
    _synth(out, "--model", "fisheye", "--image-size", "640x512", "--views", "12", "--partial", "0", "--blank", "0", "--corrupt", "0", "--seed", "7")
    code, o, err = _intrinsics(capsys, str(out), "--cols", "9", "--rows", "6", "--square", "0.025", "--model", "auto", "--bundle", str(tmp_path / "b.yaml"), "--json")
    assert code == 0, err
    s = json.loads(o)["cameras"][0]
    assert s["model"] == "fisheye"
    truth = load_board_truth(out)
    K = np.asarray(s["K"])
    for i, j, key in ((0, 0, "fx"), (1, 1, "fy"), (0, 2, "cx"), (1, 2, "cy")):
        true = truth.camera.K[i, j]
        assert abs(K[i, j] - true) < 3 * s["sigma"][key] + 0.05, (key, K[i, j], true)
    rows = {r["model"]: r for r in s["model_choice"]["table"]}
    assert rows["pinhole5"]["rms_px"] > 5 * s["rms_px"]


def test_rendered_charuco_stereo_pairs_by_ids(tmp_path, capsys):
    out = tmp_path / "cst"
    _synth(out, "--board", "charuco", "--cols", "8", "--rows", "6", "--square", "0.03", "--marker", "0.022", "--dict", "DICT_4X4_1000", "--image-size", "640x480", "--views", "9", "--partial", "1", "--blank", "0", "--corrupt", "0", "--stereo-baseline", "0.1", "--seed", "6")
    code, o, err = _intrinsics(capsys, str(out / "cam0"), "--board", "charuco", "--cols", "8", "--rows", "6", "--square", "0.03", "--marker", "0.022", "--right", str(out / "cam1"), "--bundle", str(tmp_path / "b.yaml"), "--json", "--no-crossval")
    assert code == 0, err
    t = json.loads((out / "truth.json").read_text())
    s = json.loads(o)["stereo"]
    assert s["pairs"] >= 8
    _deg, m = geometry.pose_error(np.asarray(s["T_cam1_cam0"]), np.asarray(t["stereo"]["T_cam1_cam0"]))
    assert m < 3 * s["sigma"]["baseline_m"] + 3e-4
    assert abs(s["baseline_m"] - 0.1) < 3 * s["sigma"]["baseline_m"] + 3e-4


def test_rendered_video_frames_sampled_sharp_and_novel(tmp_path, capsys):
    """`synth board --video`: the board moves between 10 key poses (motion-blurred in between, median ≈ 12 px per
    exposure). The kept frames are sharp, one per pose, and give the true intrinsics."""
    out = tmp_path / "vid"
    _synth(out, "--image-size", "640x480", "--views", "10", "--partial", "0", "--blank", "0", "--corrupt", "0", "--video", "6", "--seed", "12")
    code, o, err = _intrinsics(capsys, str(out / "video.avi"), "--cols", "9", "--rows", "6", "--square", "0.025", "--bundle", str(tmp_path / "b.yaml"), "--json", "--no-crossval")
    assert code == 0, err
    s = json.loads(o)["cameras"][0]
    t = json.loads((out / "truth.json").read_text())
    frames = t["video"]["frames"]
    from radarcal.bundle import load_session

    arrays, _ = load_session(load_bundle(tmp_path / "b.yaml"), "intrinsics/cam0")
    kept = [int(n.rsplit("#frame", 1)[1]) for n in arrays["names"]]
    assert 8 <= len(kept) <= 14 and len(kept) < len(frames) / 3
    assert max(frames[k]["motion_blur_px"] for k in kept) < 5.0
    truth = load_board_truth(out)
    K = np.asarray(s["K"])
    for i, j, key in ((0, 0, "fx"), (1, 1, "fy"), (0, 2, "cx"), (1, 2, "cy")):
        assert abs(K[i, j] - truth.camera.K[i, j]) < 3 * s["sigma"][key] + 0.05, key


@pytest.mark.slow
def test_rendered_good_practice_plan_1280x1024(tmp_path, capsys):
    """Rendered images (the synth renderer) of the good-practice capture plan of the corner-level simulation (4 mm
    lens, 30 close views of a 14x10 board, tilts 0-10°, 20-30°, 45-55°; `synth board` has no tilt/distance
    options, so the poses come from `simulate_good_practice_views`): |Δfx|,|Δfy|,|Δcx|,|Δcy| < 0.3 px (measured
    ≤ 0.05 px on seeds 1-4), most strong-tilt views kept."""
    import cv2

    from radarcal.board import BoardSpec
    from radarcal.synth.intrinsics_views import radar_station_camera, simulate_good_practice_views
    from radarcal.synth.board import BoardRenderer, RenderSettings

    cam = radar_station_camera()
    board = BoardSpec("chessboard", 14, 10, 0.03)
    sim = simulate_good_practice_views(cam, board, 30, 0.0, np.random.default_rng(2), margin_px=40)
    renderer = BoardRenderer(cam, board, RenderSettings())
    rng = np.random.default_rng(2)
    out = tmp_path / "good"
    out.mkdir()
    for k, T in enumerate(sim.T_cam_board):
        cv2.imwrite(str(out / f"img_{k:03d}.png"), renderer.render(T, rng))
    code, o, err = _intrinsics(capsys, str(out), "--cols", "14", "--rows", "10", "--square", "0.03", "--bundle", str(tmp_path / "b.yaml"), "--json")
    assert code == 0, err
    s = json.loads(o)["cameras"][0]
    K = np.asarray(s["K"])
    err_px = np.array([K[0, 0] - cam.fx, K[1, 1] - cam.fy, K[0, 2] - cam.cx, K[1, 2] - cam.cy])
    assert np.all(np.abs(err_px) < 0.3), err_px
    assert s["views_used"] >= 26, s["rejected"]

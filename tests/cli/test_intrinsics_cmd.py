"""``radarcal intrinsics`` end to end on real image sets, bad inputs and a video."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from radarcal.bundle import load_bundle, load_session
from radarcal.cli.main import main

CHESS_OPTS = ["--cols", "9", "--rows", "6", "--square", "0.025"]
CHARUCO_OPTS = ["--board", "charuco", "--cols", "8", "--rows", "8", "--square", "0.0254", "--marker", "0.01905", "--dict", "DICT_4X4_1000"]


def _run(capsys, args):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_opencv_stereo_end_to_end(shared, tmp_path, capsys):
    d = shared("opencv_stereo_chessboard")
    bundle = tmp_path / "calib.yaml"
    left = sorted(str(p) for p in d.glob("left*.jpg"))
    code, out, err = _run(capsys, ["intrinsics", *left, *CHESS_OPTS, "--bundle", str(bundle), "--right", str(d / "right*.jpg"), "--json"])
    assert code == 0, err
    s = json.loads(out)
    c0, c1 = s["cameras"]
    assert c0["camera"] == "cam0" and c1["camera"] == "cam1"
    mono0, mono1 = c0["mono"], c1["mono"]
    assert mono0["rms_px"] <= 0.18 and abs(np.asarray(mono0["K"])[0][0] - 533.30) < 1.0
    assert abs(np.asarray(mono1["K"])[0][0] - 537.4) < 1.0
    # written: the joint stereo refinement; mrcal's joint solve (derived/mrcal2.2_stereo_*.cameramodel): 533.89, 537.47
    assert abs(np.asarray(c0["K"])[0][0] - 533.89) < 1.0 and abs(np.asarray(c1["K"])[0][0] - 537.47) < 1.0
    assert c0["views_used"] == 13 and not c0["rejected"]
    assert abs(s["stereo"]["baseline_m"] - 0.08315) < 0.0003
    b = load_bundle(bundle)
    assert set(b.cameras) >= {"cam0", "cam1"}
    e = b.cameras["cam0"]
    assert e.rms_px == pytest.approx(c0["rms_px"]) and set(e.sigma) >= {"fx", "fy", "cx", "cy", "k1"}
    assert e.camera.fx == pytest.approx(np.asarray(c0["K"])[0][0])
    assert e.provenance.command.startswith("radarcal") and len(e.provenance.inputs_sha256) == 64
    T = b.T("cam1", "cam0")
    assert abs(np.linalg.norm(T[:3, 3]) - 0.08315) < 0.0003
    arrays, meta = load_session(b, "intrinsics/cam0")
    n = len(arrays["corners_uv"])
    assert n == 13 * 54
    for k in ("residuals", "object_points", "corner_view", "corner_ids", "inliers"):
        assert len(arrays[k]) == n
    assert arrays["rvecs"].shape == (13, 3) and arrays["names"].shape == (13,)
    assert arrays["uncertainty_sigma_px"].shape == (len(arrays["uncertainty_v"]), len(arrays["uncertainty_u"]))
    assert arrays["crossval_diff_px"].shape == arrays["crossval_sigma_px"].shape
    assert meta["camera"] == "cam0"
    st, _ = load_session(b, "stereo/cam0_cam1")
    assert st["T_cam1_cam0"].shape == (4, 4)


def test_bad_files_are_named_and_do_not_stop_the_run(shared, tmp_path, capsys):
    d = shared("opencv_stereo_chessboard")
    src = tmp_path / "imgs"
    src.mkdir()
    for p in sorted(d.glob("left*.jpg"))[:8]:
        (src / p.name).symlink_to(p)
    cv2.imwrite(str(src / "blank.png"), np.full((480, 640), 200, np.uint8))
    (src / "corrupt.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg" + bytes(range(256)))
    (src / "empty.png").write_bytes(b"")
    cv2.imwrite(str(src / "small.png"), cv2.resize(cv2.imread(str(d / "left12.jpg")), (320, 240)))
    bundle = tmp_path / "b.yaml"
    code, out, err = _run(capsys, ["intrinsics", str(src), *CHESS_OPTS, "--bundle", str(bundle), "--json", "--no-crossval"])
    assert code == 0, err
    s = json.loads(out)["cameras"][0]
    rej = {Path(k).name: v for k, v in s["rejected"].items()}
    assert rej["blank.png"] == "no board"
    assert rej["corrupt.jpg"].startswith("unreadable")
    assert rej["empty.png"].startswith("unreadable")
    assert "image size 320x240 differs" in rej["small.png"]
    assert s["views_used"] == 8
    # the human output names them too
    code, out, err = _run(capsys, ["intrinsics", str(src), *CHESS_OPTS, "--bundle", str(bundle), "--no-crossval"])
    assert code == 0 and "rejected" in out and "corrupt.jpg: unreadable" in out and "blank.png: no board" in out


def test_wrong_board_size_is_an_input_error_with_a_hint(shared, tmp_path, capsys):
    d = shared("opencv_stereo_chessboard")
    left = sorted(str(p) for p in d.glob("left0*.jpg"))[:4]
    code, out, err = _run(capsys, ["intrinsics", *left, "--cols", "10", "--rows", "6", "--square", "0.025", "--bundle", str(tmp_path / "b.yaml")])
    assert code == 2
    assert err.startswith("error: ") and "no 10x6 chessboard found" in err and "a 9x6 chessboard" in err
    assert "Traceback" not in err
    assert not (tmp_path / "b.yaml").exists()  # nothing half-written


def test_missing_source_and_bad_options(tmp_path, capsys):
    code, _out, err = _run(capsys, ["intrinsics", str(tmp_path / "nope*.png"), *CHESS_OPTS, "--bundle", str(tmp_path / "b.yaml")])
    assert code == 2 and "no such file" in err
    code, _out, err = _run(capsys, ["intrinsics", str(tmp_path), "--board", "charuco", "--cols", "8", "--rows", "8", "--square", "0.02", "--marker", "0.02",
                                   "--bundle", str(tmp_path / "b.yaml")])  # fmt: skip
    assert code == 2 and "marker" in err  # a marker as large as the square (without --marker: 0.75 x --square)
    code, _out, err = _run(capsys, ["intrinsics", str(tmp_path), *CHESS_OPTS, "--model", "poly", "--bundle", str(tmp_path / "b.yaml")])
    assert code == 2 and "--model" in err


def test_photonvision_charuco_legacy_and_chessboard(shared, tmp_path, capsys):
    d = shared("photonvision_lifecam_hd3000")
    bundle = tmp_path / "pv.yaml"
    code, out, err = _run(capsys, ["intrinsics", str(d / "charuco_legacy_640x480"), *CHARUCO_OPTS, "--bundle", str(bundle), "--json", "--no-crossval"])
    assert code == 0, err
    s = json.loads(out)["cameras"][0]
    assert s["charuco_layout"]["legacy"] is True and s["views_used"] >= 14
    assert s["rms_px"] < 0.3
    K = np.asarray(s["K"])
    assert abs(K[0, 2] - 320) < 32 and abs(K[1, 2] - 240) < 24  # PhotonVision's own test: within 10 % of the centre
    code, out, err = _run(capsys, ["intrinsics", str(d / "chessboard_640x480"), "--cols", "10", "--rows", "10", "--square", "0.0254", "--camera", "lifecam", "--bundle", str(bundle), "--json", "--force"])
    assert code == 0, err
    s = json.loads(out)["cameras"][0]
    assert s["crossval"]["consistent"] is False and s["crossval"]["diff_median_px"] > 5
    assert any("cross-validation" in w for w in s["warnings"])
    assert set(load_bundle(bundle).cameras) == {"cam0", "lifecam"}


@pytest.mark.slow
@pytest.mark.parametrize(
    "subset,legacy",
    [("chessboard_640x480", None), ("chessboard_1280x720", None), ("charuco_640x480", False), ("charuco_1280x720", False), ("charuco_legacy_640x480", True), ("charuco_legacy_1280x720", True)],
)
def test_photonvision_all_six_sets(shared, tmp_path, capsys, subset, legacy):
    d = shared("photonvision_lifecam_hd3000") / subset
    opts = CHARUCO_OPTS if subset.startswith("charuco") else ["--cols", "10", "--rows", "10", "--square", "0.0254"]
    code, out, err = _run(capsys, ["intrinsics", str(d), *opts, "--bundle", str(tmp_path / "b.yaml"), "--json", "--no-crossval"])
    assert code == 0, err
    s = json.loads(out)["cameras"][0]
    if legacy is not None:
        assert s["charuco_layout"]["legacy"] is legacy
    w, h = s["image_size"]
    K = np.asarray(s["K"])
    assert abs(K[0, 2] - w / 2) < 0.1 * w and abs(K[1, 2] - h / 2) < 0.1 * h
    assert s["views_used"] >= 10 and s["rms_px"] < 0.4


def test_video_source_sampled_by_novelty(shared, tmp_path, capsys):
    d = shared("opencv_stereo_chessboard")
    video = tmp_path / "sweep.avi"
    wr = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    assert wr.isOpened()
    for p in sorted(d.glob("left*.jpg")):
        img = cv2.imread(str(p))
        for _ in range(4):  # a slow sweep: every pose held for 4 frames
            wr.write(img)
    wr.release()
    code, out, err = _run(capsys, ["intrinsics", str(video), *CHESS_OPTS, "--bundle", str(tmp_path / "v.yaml"), "--json", "--no-crossval"])
    assert code == 0, err
    s = json.loads(out)["cameras"][0]
    assert 8 <= s["views_total"] <= 13  # duplicates gated out
    assert abs(np.asarray(s["K"])[0][0] - 533.3) < 3.0

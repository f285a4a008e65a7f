"""``radarcal intrinsics`` inputs beyond images: corner files of other tools (CSV, mrcal .vnl), and the hints a
wrong board size or dictionary gets."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from radarcal import geometry
from radarcal.board import BoardSpec, object_points
from radarcal.bundle import load_bundle
from radarcal.camera import Camera
from radarcal.cli.main import main

TRUE = Camera((1280, 1024), [[1000.0, 0, 641.3], [0, 1002.0, 509.7], [0, 0, 1]], [-0.12, 0.07, 0.0005, -0.0003, 0.0])


def _views(n: int = 24, seed: int = 1):
    """Board views of a 9x6 chessboard seen by TRUE from varied poses (every corner inside the image)."""
    rng = np.random.default_rng(seed)
    obj = object_points(BoardSpec("chessboard", 9, 6, 0.05))
    out = []
    while len(out) < n:
        T = geometry.T_from_xyz_rpy_deg(rng.uniform(-0.35, 0.1), rng.uniform(-0.3, 0.05), rng.uniform(0.8, 1.6), rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-20, 20))
        uv, valid, _ = TRUE.project_from(T, obj)
        if valid.all() and np.all((uv > 5) & (uv < np.array(TRUE.image_size) - 5)):
            out.append(uv + rng.normal(scale=0.1, size=uv.shape))
    return out


@pytest.mark.parametrize("with_ids", [True, False])
def test_corner_csv_recovers_the_camera(tmp_path, capsys, with_ids):
    rows = ["image,id,u,v" if with_ids else "image,u,v"]
    for k, uv in enumerate(_views()):
        for i, (u, v) in enumerate(uv):
            rows.append(f"view{k:02d}.png,{i},{u:.4f},{v:.4f}" if with_ids else f"view{k:02d}.png,{u:.4f},{v:.4f}")
    f = tmp_path / "corners.csv"
    f.write_text("\n".join(rows) + "\n")
    b = tmp_path / "b.yaml"
    code = main(["intrinsics", "--corners", str(f), "--image-size", "1280x1024", "--cols", "9", "--rows", "6", "--square", "0.05", "-b", str(b), "--json", "--no-crossval"])
    out = capsys.readouterr()
    assert code == 0, out.err
    cam = load_bundle(b).camera("cam0")
    s = json.loads(out.out)["cameras"][0]
    for k, got, true in zip(("fx", "fy", "cx", "cy"), (cam.fx, cam.fy, cam.cx, cam.cy), (TRUE.fx, TRUE.fy, TRUE.cx, TRUE.cy)):
        assert abs(got - true) < 4 * s["sigma"][k] and s["sigma"][k] < 1.0, (k, got, true, s["sigma"][k])
    assert s["views_used"] == 24


def test_corner_file_errors(tmp_path, capsys):
    f = tmp_path / "c.vnl"
    f.write_text("# filename x y weight\nframe0.jpg 1 2 1\n")
    b = tmp_path / "b.yaml"
    assert main(["intrinsics", "--corners", str(f), "--image-size", "640x480", "--cols", "9", "--rows", "6", "--square", "0.05", "-b", str(b)]) == 2
    assert "1 corner rows, but the board has 54 inner corners" in capsys.readouterr().err
    assert main(["intrinsics", "--corners", str(f), "--cols", "9", "--rows", "6", "--square", "0.05", "-b", str(b)]) == 2
    assert "--image-size" in capsys.readouterr().err
    assert not b.exists()


@pytest.mark.slow
def test_mrcal_vnl_through_the_command(shared, tmp_path, capsys):
    """mrcal's real fisheye corners as shipped (docs/intrinsics.md): the rational model lands nearer the published mrcal
    OPENCV8 solve (fx 2073.87, cx 3004.69, cy 1997.38) than plain calibrateCamera did on either install measured (fx 2070.72,
    RMS 1.364 px; OpenCV 5.0.0.93: fx 2134.13, RMS 4.246 px)."""
    d = shared("mrcal_nikon_d750_samyang12mm_fisheye_corners")
    b = tmp_path / "b.yaml"
    code = main(["intrinsics", "--corners", str(d / "corners.vnl"), "--image-size", "6016x4016", "--cols", "10", "--rows", "10", "--square", "0.077",
                 "--model", "pinhole8", "-b", str(b), "--json", "--no-crossval"])  # fmt: skip
    s = json.loads(capsys.readouterr().out)["cameras"][0]
    assert code == 0 and s["views_used"] == 186
    K = np.asarray(s["K"])
    assert abs(K[0, 0] - 2073.87) < 2.0 and abs(K[0, 0] - 2073.87) < abs(2070.72 - 2073.87)
    assert abs(K[0, 2] - 3004.69) < 2.0 and abs(K[1, 2] - 1997.38) < 2.0
    assert s["rms_px"] < 1.364


def test_wrong_board_size_is_named(shared, tmp_path, capsys):
    d = shared("opencv_stereo_chessboard")
    code = main(["intrinsics", str(d / "left01.jpg"), "--cols", "10", "--rows", "6", "--square", "0.025", "-b", str(tmp_path / "b.yaml"), "--workers", "1"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"error: {d / 'left01.jpg'}: ")  # the one file, not "."
    assert "a 9x6 chessboard (inner corners) is visible but --cols 10 --rows 6 was given" in err


def test_wrong_dictionary_is_named(tmp_path, capsys):
    spec = BoardSpec("charuco", 8, 8, 0.03, 0.022, "DICT_4X4_1000", legacy=False)
    img = spec.cv_board().generateImage((800, 800), marginSize=40)
    img = cv2.GaussianBlur(img, (3, 3), 0.8)
    p = tmp_path / "board.png"
    cv2.imwrite(str(p), img)
    code = main(["intrinsics", str(p), "--board", "charuco", "--cols", "8", "--rows", "8", "--square", "0.03", "--marker", "0.022", "--dict", "DICT_5X5_100",
                 "-b", str(tmp_path / "b.yaml"), "--workers", "1"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "ArUco markers of DICT_4X4_1000 are visible but --dict DICT_5X5_100 was given" in err, err


def test_pinhole4_exports_to_kalibr(tmp_path, capsys):
    """The default pinhole5 camera has k3, which Kalibr's radtan cannot hold: the refusal names --model pinhole4, and
    a pinhole4 calibration exports (k3 = 0 exactly, the fit still recovers the camera)."""
    rows = ["image,u,v"] + [f"v{k:02d}.png,{u:.4f},{v:.4f}" for k, uv in enumerate(_views()) for u, v in uv]
    f = tmp_path / "corners.csv"
    f.write_text("\n".join(rows) + "\n")
    opts = ["--corners", str(f), "--image-size", "1280x1024", "--cols", "9", "--rows", "6", "--square", "0.05", "--no-crossval"]
    b5, b4 = tmp_path / "b5.yaml", tmp_path / "b4.yaml"
    assert main(["intrinsics", *opts, "-b", str(b5)]) == 0
    capsys.readouterr()
    assert main(["bundle", "export", str(b5), "--camera", "cam0", "--format", "kalibr"]) == 2
    assert "--model pinhole4" in capsys.readouterr().err
    assert main(["intrinsics", *opts, "--model", "pinhole4", "-b", str(b4)]) == 0
    cam = load_bundle(b4).camera("cam0")
    assert cam.dist.size == 4 and abs(cam.fx - TRUE.fx) < 3.0 and abs(cam.dist[0] - TRUE.dist[0]) < 0.01
    capsys.readouterr()
    assert main(["bundle", "export", str(b4), "--camera", "cam0", "--format", "kalibr"]) == 0
    assert "radtan" in capsys.readouterr().out

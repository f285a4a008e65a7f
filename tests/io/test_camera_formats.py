"""Camera-intrinsics interop: ROS / OpenCV / Kalibr / JSON round trips and the real reference files."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from radarcal.bundle import load_bundle
from radarcal.camera import Camera
from radarcal.cli.main import main
from radarcal.errors import InputError
from radarcal.io import export_camera, import_camera
from radarcal.io.camera_formats import detect_camera_format

# awkward doubles on purpose: 17 significant digits, tiny and negative values
K_MLCC = [[863.590518437255, 0.116814496662654, 621.666074631063], [0, 863.100180533059, 533.971978652819], [0, 0, 1]]
CAMS = {
    "radtan4": Camera((640, 480), [[535.9157339616320, 0, 342.28315473308373], [0, 535.91573396163199, 235.57082909788173], [0, 0, 1]],
                      [-0.26637260909660682, -0.038588898922304653, 0.0017831947042852964, -0.00028122100441115472]),
    "radtan5_skew": Camera((1280, 1024), K_MLCC, [-0.0944205499243979, 0.0946727677776504, -0.00807970960613932, 8.07461209775283e-05, 6.52716646875879e-05]),
    "rational8": Camera((1920, 1080), [[1364.4512345678901, 0, 958.32700000000011], [0, 1366.4612345678901, 535.07400000000001], [0, 0, 1]],
                        [0.1234567890123456, -0.2345678901234567, 1e-5, -3.3e-6, 0.01, 0.51, -0.0123456789, 1e-9]),
    "thinprism12": Camera((1280, 1024), [[900.1, 0, 640.2], [0, 899.9, 511.7], [0, 0, 1]], np.arange(1, 13) * np.array([-1.1e-1, 1e-2, 1e-4, -1e-4, 1e-3, 1e-2, 1e-3, 1e-4, 1e-5, -1e-5, 2e-5, -2e-5])),
    "fisheye": Camera((1280, 1024), [[410.51234567890123, 0, 640.1], [0, 410.25, 512.3], [0, 0, 1]], [0.021, -0.0043, 0.0011, -0.00020000000000000001], model="fisheye"),
}


def _same(a: Camera, b: Camera) -> None:
    assert a.model == b.model and a.image_size == b.image_size
    assert np.array_equal(a.K, b.K), (a.K - b.K)
    assert np.array_equal(a.dist, b.dist), (a.dist - b.dist)


@pytest.mark.parametrize("name", sorted(CAMS))
@pytest.mark.parametrize("fmt", ["ros", "opencv", "json"])
def test_export_import_round_trip_is_exact(tmp_path, name, fmt):
    cam = CAMS[name]
    text = export_camera(cam, fmt, "cam0")
    p = tmp_path / f"cam.{'json' if fmt == 'json' else 'yaml'}"
    p.write_text(text)
    back, detected = import_camera(p)
    assert detected == fmt
    _same(back, cam)


def test_ros_export_is_a_real_camera_info(tmp_path):
    cam = CAMS["radtan5_skew"]
    d = yaml.safe_load(export_camera(cam, "ros", "left"))
    assert d["image_width"] == 1280 and d["image_height"] == 1024 and d["camera_name"] == "left"
    assert d["distortion_model"] == "plumb_bob" and d["camera_matrix"]["rows"] == 3
    assert d["camera_matrix"]["data"] == np.asarray(K_MLCC, float).ravel().tolist()
    assert d["projection_matrix"]["cols"] == 4 and len(d["projection_matrix"]["data"]) == 12
    assert yaml.safe_load(export_camera(CAMS["rational8"], "ros"))["distortion_model"] == "rational_polynomial"
    assert yaml.safe_load(export_camera(CAMS["fisheye"], "ros"))["distortion_model"] == "equidistant"


def test_opencv_export_reads_back_with_cv2(tmp_path):
    import cv2

    cam = CAMS["rational8"]
    p = tmp_path / "cam.yaml"
    p.write_text(export_camera(cam, "opencv"))
    assert p.read_text().startswith("%YAML:1.0\n")  # the header older tools (and OpenCV 4) expect
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    assert np.array_equal(fs.getNode("camera_matrix").mat(), cam.K)
    assert np.array_equal(fs.getNode("distortion_coefficients").mat().ravel(), cam.dist)
    assert int(fs.getNode("image_width").real()) == 1920
    fs.release()


@pytest.mark.parametrize("name", ["radtan4", "fisheye"])
def test_kalibr_round_trip(tmp_path, name):
    cam = CAMS[name]
    text = export_camera(cam, "kalibr", "cam1")
    d = yaml.safe_load(text)
    assert d["cam1"]["camera_model"] == "pinhole" and d["cam1"]["resolution"] == list(cam.image_size)
    assert d["cam1"]["distortion_model"] == ("equidistant" if cam.model == "fisheye" else "radtan")
    assert d["cam1"]["intrinsics"] == [cam.fx, cam.fy, cam.cx, cam.cy]
    p = tmp_path / "camchain.yaml"
    p.write_text(text)
    back, fmt = import_camera(p)
    assert fmt == "kalibr"
    _same(back, cam)


def test_kalibr_five_coefficients_with_zero_k3(tmp_path):
    cam = Camera((640, 480), CAMS["radtan4"].K, [*CAMS["radtan4"].dist, 0.0])
    p = tmp_path / "camchain.yaml"
    p.write_text(export_camera(cam, "kalibr"))
    back, _ = import_camera(p)
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.dist, cam.dist[:4])


def test_kalibr_refuses_what_it_cannot_hold():
    with pytest.raises(InputError, match="Kalibr radtan has 4 coefficients"):
        export_camera(CAMS["radtan5_skew"], "kalibr")
    with pytest.raises(InputError, match="Kalibr radtan has 4 coefficients"):
        export_camera(CAMS["rational8"], "kalibr")


def test_kalibr_multi_camera_select(tmp_path):
    chain = {
        "cam0": {"camera_model": "pinhole", "intrinsics": [500.0, 501.0, 320.0, 240.0], "distortion_model": "radtan", "distortion_coeffs": [0.1, -0.2, 0.001, 0.002], "resolution": [640, 480]},
        "cam1": {"camera_model": "pinhole", "intrinsics": [400.0, 401.0, 330.0, 250.0], "distortion_model": "equidistant", "distortion_coeffs": [0.01, 0.02, 0.003, 0.004], "resolution": [752, 480],
                 "T_cn_cnm1": np.eye(4).tolist()},
    }
    p = tmp_path / "camchain.yaml"
    p.write_text(yaml.safe_dump(chain))
    cam0, _ = import_camera(p)
    cam1, _ = import_camera(p, "cam1")
    assert cam0.fx == 500.0 and cam0.model == "pinhole" and cam0.image_size == (640, 480)
    assert cam1.fx == 400.0 and cam1.model == "fisheye" and cam1.image_size == (752, 480)
    np.testing.assert_array_equal(cam1.dist, [0.01, 0.02, 0.003, 0.004])
    chain["cam1"]["camera_model"] = "omni"
    p.write_text(yaml.safe_dump(chain))
    with pytest.raises(InputError, match="unsupported model omni"):
        import_camera(p, "cam1")


def test_import_real_ros_camera_info_layout(tmp_path):
    """The layout camera_calibration's cameracalibrator writes (ost.yaml)."""
    text = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [430.215550, 0.000000, 306.691343, 0.000000, 430.531693, 227.224800, 0.000000, 0.000000, 1.000000]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.337586, 0.111617, -0.000026, 0.000783, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.000000, 0.000000, 0.000000, 0.000000, 1.000000, 0.000000, 0.000000, 0.000000, 1.000000]
projection_matrix:
  rows: 3
  cols: 4
  data: [337.414581, 0.000000, 304.955452, 0.000000, 0.000000, 375.484619, 227.021358, 0.000000, 0.000000, 0.000000, 1.000000, 0.000000]
"""
    p = tmp_path / "ost.yaml"
    p.write_text(text)
    cam, fmt = import_camera(p)
    assert fmt == "ros"
    np.testing.assert_array_equal(cam.K, [[430.215550, 0, 306.691343], [0, 430.531693, 227.224800], [0, 0, 1]])
    np.testing.assert_array_equal(cam.dist, [-0.337586, 0.111617, -0.000026, 0.000783, 0.0])


def test_detect_format():
    assert detect_camera_format("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n") == "opencv"
    assert detect_camera_format('{"K": 1}') == "json"
    assert detect_camera_format("image_width: 1\ncamera_matrix:\n  data: []\ndistortion_model: plumb_bob\n") == "ros"
    assert detect_camera_format("cam0:\n  camera_model: pinhole\n  intrinsics: [1, 2, 3, 4]\n") == "kalibr"
    assert detect_camera_format("hello: world\n") == "unknown"


BAD_FILES = {
    "unknown.yaml": ("hello: world\n", "unrecognised camera file"),
    "broken_opencv.yaml": ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: [[[\n", "OpenCV FileStorage cannot parse the file (line 5: "),
    "no_k.yaml": ("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n", "no camera matrix"),
    "no_size.yaml": ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [500., 0., 320., 0., 500., 240., 0., 0., 1.]\n", "no image size in the file"),
    "neg_f.json": (json.dumps({"image_size": [640, 480], "K": [[-5, 0, 320], [0, 5, 240], [0, 0, 1]], "dist": [0, 0, 0, 0, 0]}), "focal lengths must be positive"),
    "bad.json": ('{"image_size": [640, 480], "K": ', "radarcal JSON camera"),
    "missing_k.json": (json.dumps({"image_size": [640, 480]}), "radarcal JSON camera: bad or missing field"),
    "ros_missing.yaml": ("camera_matrix:\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\ndistortion_model: plumb_bob\n", "ROS camera_info: missing key"),
    "ros_bad_model.yaml": ("image_width: 4\nimage_height: 4\ncamera_matrix:\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\ndistortion_model: weird\n", "unsupported distortion model 'weird'"),
    "ros_bad_dist.yaml": ("image_width: 4\nimage_height: 4\ncamera_matrix:\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\ndistortion_model: plumb_bob\ndistortion_coefficients:\n  data: [1, 2, 3]\n", "pinhole needs 4/5/8/12"),
    "bad_yaml.yaml": ("camera_matrix: [\ndistortion_model: {", "not valid YAML"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_camera_files_name_the_file(tmp_path, name):
    text, msg = BAD_FILES[name]
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(InputError) as e:
        import_camera(p)
    assert e.value.source == str(p) and msg in e.value.message and "\n" not in e.value.message


def test_missing_camera_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        import_camera(tmp_path / "nope.yaml")


def test_unknown_export_format():
    with pytest.raises(InputError, match="unknown export format"):
        export_camera(CAMS["radtan4"], "matlab")


# --- the real reference files, through `radarcal bundle import` -----------------------------------------------------
def test_bundle_import_opencv_left_intrinsics(shared, tmp_path, capsys):
    src = shared("opencv_stereo_chessboard") / "reference" / "left_intrinsics.yml"
    bundle = tmp_path / "rig.yaml"
    assert main(["bundle", "import", str(bundle), str(src), "--camera", "cam0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["format"] == "opencv"
    cam = load_bundle(bundle).camera("cam0")
    # the values written in the file (SOURCE.md: fx=fy=535.9157, cx=342.2832, cy=235.5708)
    np.testing.assert_array_equal(cam.K, [[5.3591573396163199e+02, 0, 3.4228315473308373e+02], [0, 5.3591573396163199e+02, 2.3557082909788173e+02], [0, 0, 1]])
    np.testing.assert_array_equal(cam.dist, [-2.6637260909660682e-01, -3.8588898922304653e-02, 1.7831947042852964e-03, -2.8122100441115472e-04, 2.3839153080878486e-01])
    assert cam.image_size == (640, 480) and cam.model == "pinhole"
    assert out["K"] == cam.K.tolist() and out["dist"] == cam.dist.tolist()


def test_bundle_import_mlcc_left_yaml(shared, tmp_path, capsys):
    src = shared("mlcc_livox_mid100_scene2") / "calib" / "left.yaml"
    bundle = tmp_path / "rig.yaml"
    assert main(["bundle", "import", str(bundle), str(src), "--camera", "left"]) == 0
    assert "imported left" in capsys.readouterr().out
    b = load_bundle(bundle)
    cam = b.camera("left")
    np.testing.assert_array_equal(cam.K, K_MLCC)  # CameraMat incl. the 0.1168 skew
    np.testing.assert_array_equal(cam.dist, [-0.0944205499243979, 0.0946727677776504, -0.00807970960613932, 8.07461209775283e-05, 6.52716646875879e-05])
    assert cam.image_size == (1280, 1024)
    assert b.cameras["left"].extra == {"imported_from": "opencv"}
    assert b.cameras["left"].provenance.command.startswith("radarcal") and len(b.cameras["left"].provenance.inputs_sha256) == 64


def test_bundle_import_stereo_select_right(shared, tmp_path, capsys):
    src = shared("opencv_stereo_chessboard") / "reference" / "intrinsics.yml"
    bundle = tmp_path / "rig.yaml"
    # the file records no image size: a clear error, then --image-size from SOURCE.md (640x480)
    assert main(["bundle", "import", str(bundle), str(src), "--camera", "cam1", "--select", "right"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {src}: no image size") and "--image-size" in err and err.count("\n") == 1
    assert not bundle.exists()
    assert main(["bundle", "import", str(bundle), str(src), "--camera", "cam1", "--select", "right", "--image-size", "640x480"]) == 0
    assert main(["bundle", "import", str(bundle), str(src), "--camera", "cam0", "--select", "left", "--image-size", "640x480"]) == 0
    b = load_bundle(bundle)
    right, left = b.camera("cam1"), b.camera("cam0")
    np.testing.assert_array_equal(right.K, [[5.3480326845051309e+02, 0, 3.3455744527912015e+02], [0, 5.3480326845051309e+02, 2.4205324573376600e+02], [0, 0, 1]])
    np.testing.assert_array_equal(right.dist, [-1.6916358306948096e-01, -1.1214173641213163e-01, 0, 0, 0])
    np.testing.assert_array_equal(left.K, [[5.3480326845051309e+02, 0, 3.3568643204394891e+02], [0, 5.3480326845051309e+02, 2.4066183054066337e+02], [0, 0, 1]])
    np.testing.assert_array_equal(left.dist, [2.9589439552724328e-01, -1.0354662043042675e+00, 0, 0, 0])
    assert right.image_size == left.image_size == (640, 480)

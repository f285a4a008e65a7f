"""Two cameras through the CLI: `field-pnp --camera` / `lidar-camera --camera` per camera, the one-line error without
--camera, stereo-derived entries, the cross-check in `bundle show` and `field-pnp`, and `bundle validate` flagging a
wrong cam1 pose. Scenes: radarcal.synth.two_camera (family 1: LiDAR-linked station, family 2: stereo, random field)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle
from radarcal.cli.main import main
from radarcal.synth.two_camera import two_camera_scene, write_two_camera_scene


def _run(capsys, *args):
    capsys.readouterr()
    code = main(list(map(str, args)))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture
def fam1(tmp_path):
    sc = two_camera_scene(1, 4)
    write_two_camera_scene(sc, tmp_path)
    return sc, tmp_path


def test_several_cameras_need_camera_and_fail_changing_nothing(fam1, capsys):
    _, d = fam1
    before = (d / "bundle.yaml").read_bytes()
    for cmd in (["field-pnp", "-b", d / "bundle.yaml", "--points", d / "picks_cam0.csv"], ["lidar-camera", "-b", d / "bundle.yaml", "--corners", d / "corners_cam0.csv"]):
        code, out, err = _run(capsys, *cmd)
        assert code == 2 and err.strip().splitlines() == ["error: --camera: the bundle has 2 cameras (cam0, cam1): pick one with --camera"]
    code, _, err = _run(capsys, "field-pnp", "-b", d / "bundle.yaml", "--camera", "cam7", "--points", d / "picks_cam0.csv")
    assert code == 2 and "no camera 'cam7'" in err and "cam0, cam1" in err
    assert (d / "bundle.yaml").read_bytes() == before


def test_per_camera_calibration_and_cross_check(fam1, capsys):
    sc, d = fam1
    b = d / "bundle.yaml"
    for cam in ("cam0", "cam1"):
        assert _run(capsys, "lidar-camera", "-b", b, "--camera", cam, "--corners", d / f"corners_{cam}.csv", "--json")[0] == 0
    code, out, _ = _run(capsys, "field-pnp", "-b", b, "--camera", "cam0", "--points", d / "picks_cam0.csv", "--json")
    assert code == 0 and json.loads(out)["cross_check"][0]["note"].startswith("cam1 has no field pose of its own")
    code, out, _ = _run(capsys, "field-pnp", "-b", b, "--camera", "cam1", "--points", d / "picks_cam1.csv", "--json")
    s = json.loads(out)
    assert code == 0 and s["camera"] == "cam1" and s["depth_source"] == "lidar" and s["lidar"] == "lidar0"
    bd = load_bundle(b)
    for cam in ("cam0", "cam1"):  # every camera: its own intrinsics, LiDAR extrinsic and field pose, near the truth
        deg, m = geometry.pose_error(bd.T(cam, "field"), sc.T_cam_field(cam))
        assert deg < 0.3 and m < 0.1, (cam, deg, m)
        deg, m = geometry.pose_error(bd.T(cam, "lidar0"), sc.T_cam_lidar[cam])
        assert deg < 0.3 and m < 0.05, (cam, deg, m)
        assert f"field_pnp/{cam}" in bd.sessions and f"lidar_camera/{cam}_lidar0" in bd.sessions
    (check,) = s["cross_check"]
    assert check["link"] == "T_cam1_lidar0 · T_cam0_lidar0" and check["n_points"] > 300 and not check["flagged"]
    assert check["cm"]["median"] < 3 * check["expected_cm"] and check["expected_cm"] < 8
    code, out, _ = _run(capsys, "bundle", "show", b)
    assert code == 0 and "cross-check cam0 vs cam1 on" in out and "FLAGGED" not in out
    code, out, _ = _run(capsys, "bundle", "validate", b)
    assert code == 0 and "flagged" not in out
    # a deliberately wrong cam1 pose (turned 0.5 deg about its vertical axis): flagged by validate and show
    wrong = geometry.T_from_rotvec(np.radians([0, 0.5, 0]), np.zeros(3)) @ bd.T("cam1", "field")
    (d / "wrong.json").write_text(json.dumps(wrong.tolist()))
    assert _run(capsys, "bundle", "set-transform", b, "cam1", "field", d / "wrong.json")[0] == 0
    code, out, _ = _run(capsys, "bundle", "validate", b, "--json")
    (w,) = json.loads(out)["warnings"]
    assert code == 0 and w.startswith("cameras cam0 and cam1: the cameras disagree")
    code, out, _ = _run(capsys, "bundle", "show", b)
    assert "FLAGGED" in out


def test_stereo_pair_derives_then_own_pose_replaces(tmp_path, capsys):
    sc = two_camera_scene(2, 3)
    write_two_camera_scene(sc, tmp_path)
    b = tmp_path / "bundle.yaml"
    code, out, _ = _run(capsys, "field-pnp", "-b", b, "--camera", "cam0", "--points", tmp_path / "picks_cam0.csv")
    assert code == 0 and "derived T_cam1_field = T_cam1_cam0 · T_cam0_field" in out
    bd = load_bundle(b)
    e = bd.transforms["T_cam1_field"]
    assert e.residual["derived_from"] == ["T_cam1_cam0", "T_cam0_field"] and e.method.startswith("derived:")
    deg, m = geometry.pose_error(e.T, sc.T_cam_field("cam1"))
    assert deg < 0.3 and m < 0.1, (deg, m)  # cam1 on the field through cam0 and the stereo pair, before clicking cam1 at all
    code, out, _ = _run(capsys, "field-pnp", "-b", b, "--camera", "cam1", "--points", tmp_path / "picks_cam1.csv", "--json")
    s = json.loads(out)
    assert code == 0 and s["derived"] == [] and s["depth_source"] == "ground"
    assert "derived_from" not in load_bundle(b).transforms["T_cam1_field"].residual
    (check,) = s["cross_check"]
    assert check["link"] == "T_cam1_cam0" and not check["flagged"] and check["cm"]["median"] < 10

"""Other tools' calibration files: KITTI calib_*.txt, OpenCalib JSON, Calib-Anything calib.txt (intrinsics and the
LiDAR -> camera extrinsic), through the readers and through `radarcal bundle import` / `set-transform`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle
from radarcal.cli.main import main
from radarcal.errors import InputError
from radarcal.io import import_camera, read_cloud, read_transform
from radarcal.io.tool_calib_files import detect_tool_format, read_tool_calib

K = np.array([[721.5377, 0, 609.5593], [0, 721.5377, 172.854], [0, 0, 1]])


def _kitti_text(T_velo_cam0: np.ndarray, R0: np.ndarray, t_cam2: np.ndarray) -> str:
    P2 = K @ np.hstack([np.eye(3), t_cam2[:, None]])
    fmt = lambda a: " ".join(f"{v:.12e}" for v in np.asarray(a).ravel())  # noqa: E731
    return "\n".join([f"P0: {fmt(K @ np.hstack([np.eye(3), np.zeros((3, 1))]))}", f"P2: {fmt(P2)}", f"R0_rect: {fmt(R0)}", f"Tr_velo_to_cam: {fmt(T_velo_cam0[:3])}", ""])


def test_kitti_chain_matches_the_projection_it_encodes(tmp_path):
    """u ~ P2 R0 Tr p must equal K T_cam2_lidar p for every point (the defining property of the chain)."""
    rng = np.random.default_rng(3)
    Tr = geometry.T_from_xyz_rpy_deg(0.02, -0.07, -0.27, -90.5, 0.3, -90.2)
    R0 = geometry.rpy_deg_to_R(0.25, -0.4, 0.56)
    t2 = np.array([0.05985, -0.00036, 0.00275])
    path = tmp_path / "calib_000001.txt"
    path.write_text(_kitti_text(Tr, R0, t2))
    assert detect_tool_format(path.read_text()) == "kitti"
    tc = read_tool_calib(path)
    p = np.column_stack([rng.uniform(5, 60, 50), rng.uniform(-10, 10, 50), rng.uniform(-2, 2, 50), np.ones(50)])
    P2 = K @ np.hstack([np.eye(3), t2[:, None]])
    R0h = np.eye(4)
    R0h[:3, :3] = R0
    uvw = (P2 @ R0h @ Tr @ p.T).T
    uvw2 = (tc.K @ tc.T_cam_lidar[:3] @ p.T).T
    np.testing.assert_allclose(uvw[:, :2] / uvw[:, 2:], uvw2[:, :2] / uvw2[:, 2:], atol=1e-6)
    np.testing.assert_allclose(tc.K, K)
    cam0 = read_tool_calib(path, camera_index=0)
    np.testing.assert_allclose(cam0.T_cam_lidar, R0h @ Tr, atol=1e-9)


def test_bad_tool_files(tmp_path):
    p = tmp_path / "calib.txt"
    p.write_text("P0: 1 0 0 0 0 1 0 0 0 0 1 0\nTr_velo_to_cam: 1 2 3 4 5 6 7 8 9 10 11 12\n")
    with pytest.raises(InputError, match="no P2"):
        read_tool_calib(p)
    p.write_text(_kitti_text(np.eye(4), np.eye(3), np.zeros(3)).replace("Tr_velo_to_cam: 1.", "Tr_velo_to_cam: 3."))
    with pytest.raises(InputError, match="not a rigid transform"):
        read_tool_calib(p)
    j = tmp_path / "x-to-y-extrinsic.json"
    j.write_text(json.dumps({"lidar-to-cam-extrinsic": {"sensor_name": "lidar", "target_sensor_name": "cam", "param": {"sensor_calib": {"data": np.eye(4).tolist()}}}}))
    with pytest.raises(InputError, match="holds no intrinsics"):
        import_camera(j)
    assert np.allclose(read_transform(j), np.eye(4))
    b = tmp_path / "b.yaml"
    assert main(["bundle", "import", str(b), str(j), "--camera", "cam0"]) == 2 and not b.exists()


def test_kitti_000008_through_the_commands(shared, tmp_path, capsys):
    """The shipped KITTI calibration: K from P2 and T_cam2_lidar as the data set's SOURCE.md derives it; every point of
    the FoV-cropped cloud projects inside the 1242x375 image (SOURCE.md: all 17,238 do)."""
    d = shared("kitti_000008")
    b = tmp_path / "b.yaml"
    assert main(["bundle", "import", str(b), str(d / "calib_000008.txt"), "--camera", "cam2", "--image-size", "1242x375"]) == 0
    bundle = load_bundle(b)
    ref = json.loads((d / "calib_000008.json").read_text())
    np.testing.assert_allclose(bundle.camera("cam2").K, ref["K"], atol=1e-9)
    T = bundle.T("cam2", "lidar0")
    rot, trans = geometry.pose_error(T, np.array(ref["T_cam2_lidar"]))
    assert rot < 1e-4 and trans < 1e-6, (rot, trans)
    pts = read_cloud(d / "000008.bin").points
    uv, valid = bundle.camera("cam2").project(geometry.transform_points(T, pts))
    inside = valid & (uv[:, 0] >= 0) & (uv[:, 0] <= 1242) & (uv[:, 1] >= 0) & (uv[:, 1] <= 375)  # SOURCE.md's check
    assert inside.all(), inside.mean()
    assert main(["bundle", "show", str(b)]) == 0
    out = capsys.readouterr().out
    assert "camera at (0.270, 0.058, -0.072) m in the LiDAR frame" in out  # the camera 27 cm ahead of the Velodyne, 7 cm below


def test_opencalib_files_through_the_commands(shared, tmp_path):
    d = shared("opencalib_road_64beam")
    b = tmp_path / "b.yaml"
    assert main(["bundle", "import", str(b), str(d / "auto" / "center_camera-intrinsic.json"), "--camera", "cam0"]) == 0
    cam = load_bundle(b).camera("cam0")
    assert cam.image_size == (1920, 1200) and np.isclose(cam.fx, 2117.31) and np.allclose(cam.dist, [-0.102933, -0.040925, 0.00057951, -0.00419933, 0.429959])
    assert main(["bundle", "set-transform", str(b), "cam0", "lidar0", str(d / "auto" / "top_center_lidar-to-center_camera-extrinsic.json")]) == 0
    T_ref = np.array([[0.00382471, -0.999992, -0.00070554, -0.0125114], [-0.0132276, 0.000654817, -0.999912, -0.379526], [0.999905, 0.00383377, -0.0132251, -0.551037], [0, 0, 0, 1]])
    assert np.abs(load_bundle(b).T("cam0", "lidar0") - T_ref).max() < 2e-5  # re-orthonormalised 6-digit rotation
    c = tmp_path / "c.yaml"
    assert main(["bundle", "import", str(c), str(d / "calibanything_1" / "calib.txt"), "--camera", "cam0", "--image-size", "1920x1200"]) == 0
    bc = load_bundle(c)
    assert np.isclose(bc.camera("cam0").fx, 2152.8) and bc.camera("cam0").dist.size == 4
    assert np.abs(bc.T("cam0", "lidar0")[:3, 3] - [-0.0323222, -0.396685, -0.0869361]).max() < 1e-9

"""`radarcal lidar-field`: writes T_field_lidar0 from a generated cloud of the real mesh; bad input is one line,
exit != 0 and nothing stored."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle
from radarcal.cli.main import main
from tests.conftest import shared_dataset


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from radarcal.field import load_field
    from radarcal.synth.lidar_field import LidarFieldSceneConfig, lidar_field_scene

    d = shared_dataset("hitsz_rmuc_field_meshes")
    mesh = d / "24_bg2align_fix1.stl"
    sc = lidar_field_scene(load_field(mesh), LidarFieldSceneConfig(seed=11, points=60_000))
    tmp = tmp_path_factory.mktemp("lf")
    np.save(tmp / "cloud.npy", sc.points_lidar)
    T0 = geometry.perturb_T(sc.T_field_lidar, 2.0, 0.3, np.random.default_rng(3))
    (tmp / "init.json").write_text(json.dumps({"T_field_lidar": T0.tolist()}))
    return tmp, mesh, sc


def test_writes_T_field_lidar(scene, capsys):
    tmp, mesh, sc = scene
    b = tmp / "calib.yaml"
    rc = main(["lidar-field", "--bundle", str(b), "--lidar", "lidar0", "--cloud", str(tmp / "cloud.npy"), "--field-mesh", str(mesh), "--init", str(tmp / "init.json"), "--max-points", "6000", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["verdict"] == "converged" and out["stored"]
    bd = load_bundle(b)
    deg, m = geometry.pose_error(bd.T("field", "lidar0"), sc.T_field_lidar)
    assert deg < 0.05 and m < 0.02
    e = bd.transforms["T_field_lidar0"]
    assert "lidar-field" in e.method and e.sigma["yaw_deg"] > 0 and e.residual["rms_m"] < 0.03
    assert bd.field_model["mesh"]["units"] == "mm"  # the bundle's field is now the mesh (by reference)


def _bytes(p):
    return p.read_bytes() if p.exists() else None


@pytest.mark.parametrize("case", ["empty", "not_a_mesh", "no_field", "no_start"])
def test_bad_input_one_line_nothing_stored(scene, tmp_path, capsys, case):
    tmp, mesh, sc = scene
    b = tmp_path / "calib.yaml"
    cloud, field = tmp / "cloud.npy", str(mesh)
    extra = ["--init", str(tmp / "init.json")]
    if case == "empty":
        cloud = tmp_path / "empty.npy"
        np.save(cloud, np.zeros((0, 3), np.float32))
    elif case == "not_a_mesh":
        field = str(tmp_path / "field.stl")
        (tmp_path / "field.stl").write_bytes(b"this is no mesh" * 20)
    elif case == "no_field":  # the points of a room far from any field: the mesh explains nothing
        cloud = tmp_path / "sky.npy"
        rng = np.random.default_rng(0)
        np.save(cloud, (rng.normal(0, 1, (20000, 3)) * [3, 3, 1] + [0, 0, 40]).astype(np.float32))
    elif case == "no_start":
        extra = []
    rc = main(["lidar-field", "--bundle", str(b), "--cloud", str(cloud), "--field-mesh", field, "--max-points", "4000", *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("error: ") and "\n" not in err
    assert not b.exists()
    assert {"empty": "empty point cloud", "not_a_mesh": "not a mesh", "no_field": "registration failed", "no_start": "no start pose"}[case] in err


def test_run_field_pose_chain_pnp_auto():
    from radarcal.bundle import Bundle
    from radarcal.cli.lidar_field_cmd import resolve_field_pose
    from radarcal.errors import InputError

    T_field_cam = geometry.T_from_xyz_rpy_deg(-0.6, 11.5, 2.5, 0, 16, -20)
    T_cam_lidar = geometry.T_from_xyz_rpy_deg(0.04, 0.09, -0.03, 1, 2, 3)
    T_chain_cam = geometry.T_from_xyz_rpy_deg(-0.58, 11.52, 2.49, 0.1, 16.1, -20.1)  # what lidar-field found
    b = Bundle()
    b.set_transform("cam0", "field", geometry.invert_T(T_field_cam))
    b.set_transform("cam0", "lidar0", T_cam_lidar)
    with pytest.raises(InputError, match="chain: needs T_field_lidar0"):
        resolve_field_pose(b, "cam0", "lidar0", "chain")
    T, src = resolve_field_pose(b, "cam0", "lidar0", "auto")
    np.testing.assert_allclose(T, T_field_cam) and "field-pnp" in src
    b.set_transform("field", "lidar0", T_chain_cam @ T_cam_lidar, residual={"verdict": "converged"})
    T, src = resolve_field_pose(b, "cam0", "lidar0", "auto")
    np.testing.assert_allclose(T, T_chain_cam, atol=1e-12)
    assert "chain" in src
    np.testing.assert_allclose(resolve_field_pose(b, "cam0", "lidar0", "pnp")[0], T_field_cam, atol=1e-12)
    b.transforms["T_field_lidar0"].residual["verdict"] = "degenerate"
    assert "field-pnp" in resolve_field_pose(b, "cam0", "lidar0", "auto")[1]


def _ros2_bag(path, parts, topics=("/livox/lidar", "/points")):
    """A ROS2 mcap bag (written by rosbags): the scene as Livox CustomMsg clouds on the first topic, a decoy
    PointCloud2 on the second (far points: a bag with several cloud topics needs --cloud-topic)."""
    from bag_writer import livox_msg, pc2_msg, typestore
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores

    ts = typestore(Stores.ROS2_HUMBLE, "livox_ros_driver2")
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        a = w.add_connection(topics[0], "livox_ros_driver2/msg/CustomMsg", typestore=ts)
        b = w.add_connection(topics[1], "sensor_msgs/msg/PointCloud2", typestore=ts)
        for k, p in enumerate(parts):
            w.write(a, (10 + k) * 10**8, ts.serialize_cdr(livox_msg(ts, "livox_ros_driver2", p, np.full(len(p), 9), 1.0 + 0.1 * k, ros1=False), "livox_ros_driver2/msg/CustomMsg"))
        decoy = np.random.default_rng(0).normal(0, 1, (3000, 3)).astype(np.float32) + [0, 0, 50]
        w.write(b, 2 * 10**9, ts.serialize_cdr(pc2_msg(ts, decoy, 2.0), "sensor_msgs/msg/PointCloud2"))
    return path


@pytest.mark.parametrize("kind", ["ros1", pytest.param("ros2", marks=pytest.mark.slow)])
def test_cloud_from_a_bag(scene, tmp_path, capsys, kind):
    """--cloud takes a ROS1 bag / ROS2 bag (rosbags-written, Livox CustomMsg): its clouds are merged into the scene
    and registered like the cloud file; a ROS2 bag with two cloud topics needs --cloud-topic."""
    from bag_writer import write_ros1_livox_bag

    tmp, mesh, sc = scene
    parts = np.array_split(sc.points_lidar.astype(np.float32), 5)
    b = tmp_path / "calib.yaml"
    args = ["lidar-field", "--bundle", str(b), "--field-mesh", str(mesh), "--init", str(tmp / "init.json"), "--max-points", "6000", "--json"]
    if kind == "ros1":
        bag = write_ros1_livox_bag(tmp_path / "scene.bag", parts, [1700000000.0 + 0.1 * k for k in range(5)])
    else:
        bag = _ros2_bag(tmp_path / "scene_ros2", parts)
        assert main([*args, "--cloud", str(bag)]) == 2
        assert "several cloud topics" in capsys.readouterr().err and not b.exists()
        args += ["--cloud-topic", "/livox/lidar"]
    rc = main([*args, "--cloud", str(bag)])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["verdict"] == "converged" and out["n_points"] == len(sc.points_lidar)
    deg, m = geometry.pose_error(load_bundle(b).T("field", "lidar0"), sc.T_field_lidar)
    assert deg < 0.05 and m < 0.02, (deg, m)

"""The cloud-source layer: ROS1/ROS2 bags (Livox CustomMsg, PointCloud2) decoded from the bag's definitions, folders,
the skip counters (per source, by reason), time order, and the static-scene reader of the calibration commands."""

from __future__ import annotations

import numpy as np
import pytest
from bag_writer import livox_msg, pc2_msg, typestore, write_ros1_livox_bag

from radarcal.errors import InputError
from radarcal.io import write_pcd
from radarcal.io.bags import BagCloudSource
from radarcal.io.cloud_sources import CloudSource, FolderCloudSource, open_cloud_source, read_scene_cloud


def test_ros1_bag_livox_custommsg(tmp_path):
    rng = np.random.default_rng(0)
    clouds = [rng.uniform(-20, 20, (n, 3)).astype(np.float32) for n in (500, 333)]
    path = write_ros1_livox_bag(tmp_path / "livox.bag", clouds, [1700000000.0, 1700000000.1])
    src = BagCloudSource(path, sensor="lidar0")
    assert isinstance(src, CloudSource) and src.topics == ["/livox/lidar"]
    got = list(src)
    src.close()
    assert len(got) == 2
    for g, c in zip(got, clouds):
        np.testing.assert_array_equal(g.points, c)
        np.testing.assert_array_equal(g.intensity, np.arange(len(c)) % 256)
    assert got[0].t == pytest.approx(1700000000.0, abs=1e-6) and got[1].t - got[0].t == pytest.approx(0.1, abs=1e-6)  # stamps absolute
    assert got[0].sensor == "lidar0" and got[0].name.startswith("/livox/lidar@")
    assert src.skipped.total == 0


@pytest.mark.parametrize("plugin", ["sqlite3", "mcap"])
def test_ros2_bag_custommsg_and_pointcloud2(tmp_path, plugin):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores

    ts = typestore(Stores.ROS2_HUMBLE, "livox_ros_driver2")
    rng = np.random.default_rng(1)
    c1 = rng.uniform(-20, 20, (257, 3)).astype(np.float32)  # odd count: CDR pads each 19-byte point to 20
    c2 = rng.uniform(-20, 20, (100, 3)).astype(np.float32)
    path = tmp_path / f"bag_{plugin}"
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3 if plugin == "sqlite3" else StoragePlugin.MCAP) as w:
        a = w.add_connection("/livox/lidar", "livox_ros_driver2/msg/CustomMsg", typestore=ts)
        b = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        w.write(a, 10**9, ts.serialize_cdr(livox_msg(ts, "livox_ros_driver2", c1, np.full(257, 9), 5.0, ros1=False), "livox_ros_driver2/msg/CustomMsg"))
        w.write(b, 2 * 10**9, ts.serialize_cdr(pc2_msg(ts, c2, 5.5), "sensor_msgs/msg/PointCloud2"))
    got = list(BagCloudSource(path, topic="/livox/lidar"))
    assert len(got) == 1
    np.testing.assert_array_equal(got[0].points, c1)
    assert (got[0].intensity == 9).all()
    got = list(BagCloudSource(path, topic="/points"))
    np.testing.assert_array_equal(got[0].points, c2)
    assert (got[0].intensity == 7).all()
    both = list(open_cloud_source(path))
    assert [len(c.points) for c in both] == [257, 100] and [c.t for c in both] == pytest.approx([5.0, 5.5])
    with pytest.raises(InputError, match="no Livox"):
        BagCloudSource(path, topic="/nope")  # checked when opened, not at the first cloud
    with pytest.raises(InputError, match="several cloud topics"):
        read_scene_cloud(path)
    scene = read_scene_cloud(path, topic="/points")
    np.testing.assert_array_equal(scene.points, c2)


def test_bag_out_of_order_and_undecodable_messages_are_counted(tmp_path):
    """Receive order differs from stamp order: the reorder buffer sorts by stamp; a message later than the buffer
    can hold, and a message that does not decode, are skipped and counted by reason (per source, not global)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores

    ts = typestore(Stores.ROS1_NOETIC, "livox_ros_driver")
    pts = np.ones((5, 3), np.float32)
    stamps = [10.0, 10.2, 10.1, 10.3, 10.4, 10.5, 9.0]  # 10.1 is late by one message (sorted); 9.0 comes after 10.5
    path = tmp_path / "o.bag"
    with Writer(path) as w:
        conn = w.add_connection("/livox/lidar", "livox_ros_driver/msg/CustomMsg", typestore=ts)
        for k, st in enumerate(stamps):
            w.write(conn, (100 + k) * 10**9, ts.serialize_ros1(livox_msg(ts, "livox_ros_driver", pts * k, np.zeros(5), st, ros1=True), "livox_ros_driver/msg/CustomMsg"))
        w.write(conn, 200 * 10**9, b"\x01\x02\x03")  # truncated message
    src = BagCloudSource(path, reorder=2, quiet=True)
    got = list(src)
    assert [c.t for c in got] == pytest.approx([10.0, 10.1, 10.2, 10.3, 10.4, 10.5])
    assert src.skipped.counts == {"out of time order": 1, "undecodable message": 1} and src.skipped.total == 2
    assert "9.000000" in " ".join(src.skipped.examples)
    src2 = BagCloudSource(path, reorder=2, quiet=True)
    assert src2.skipped.total == 0  # a new source starts from zero


def test_folder_source_counts_unreadable_files_and_scene_reader(tmp_path, capsys):
    (tmp_path / "cl").mkdir()
    for k in range(3):
        write_pcd(tmp_path / "cl" / f"{k:06d}.pcd", np.full((4, 3), k, np.float32), np.full(4, k))
    (tmp_path / "cl" / "000001.pcd").write_bytes(b"garbage")
    src = FolderCloudSource(tmp_path / "cl", hz=20.0, sensor="lidar0")
    got = list(src)
    assert [c.t for c in got] == pytest.approx([0.0, 0.1]) and [c.name for c in got] == ["000000.pcd", "000002.pcd"]
    assert got[1].sensor == "lidar0"
    assert src.skipped.counts == {"unreadable cloud file": 1}
    assert "warning: " in capsys.readouterr().err and "000001.pcd" in src.skipped.examples[0]
    one = read_scene_cloud(tmp_path / "cl" / "000002.pcd")
    assert len(one) == 4 and one.name == "000002.pcd"
    with pytest.raises(InputError, match="not found"):
        read_scene_cloud(tmp_path / "missing.pcd")
    with pytest.raises(InputError, match="unknown point-cloud format"):
        read_scene_cloud(tmp_path / "cl")
    with pytest.raises(InputError, match="not found"):
        open_cloud_source(tmp_path / "nothing")


def test_scene_from_a_bag_merges_every_cloud(tmp_path):
    rng = np.random.default_rng(3)
    clouds = [rng.uniform(-5, 5, (n, 3)).astype(np.float32) for n in (100, 80, 60)]
    path = write_ros1_livox_bag(tmp_path / "s.bag", clouds, [50.0, 50.1, 50.2])
    scene = read_scene_cloud(path)
    np.testing.assert_array_equal(scene.points, np.concatenate(clouds))
    assert scene.t == pytest.approx(50.2) and "3 clouds" in scene.name
    assert len(read_scene_cloud(path, max_clouds=2)) == 180

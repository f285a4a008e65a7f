"""Sources: ROS1/ROS2 bags (Livox CustomMsg, PointCloud2) decoded from the bag's definitions, Livox SDK1 packets,
folders with times.csv, and time pairing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io import write_pcd
from radarcal.runtime.sources import (LIVOX_CUSTOM_MSG, LIVOX_CUSTOM_POINT, CloudFrame, bag_clouds, cloud_folder, image_folder_frames,
                                      merge_by_time, open_clouds)  # fmt: skip


def _typestore(store, pkg):
    from rosbags.typesys import get_types_from_msg, get_typestore

    ts = get_typestore(store)
    ts.register(get_types_from_msg(LIVOX_CUSTOM_POINT, f"{pkg}/msg/CustomPoint"))
    ts.register(get_types_from_msg(LIVOX_CUSTOM_MSG.format(pkg=pkg), f"{pkg}/msg/CustomMsg"))
    return ts


def _livox_msg(ts, pkg, pts, refl, stamp, ros1):
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    hdr = T["std_msgs/msg/Header"](seq=1, stamp=Time(sec=int(stamp), nanosec=int((stamp % 1) * 1e9)), frame_id="livox") if ros1 else \
        T["std_msgs/msg/Header"](stamp=Time(sec=int(stamp), nanosec=int((stamp % 1) * 1e9)), frame_id="livox")  # fmt: skip
    P = T[f"{pkg}/msg/CustomPoint"]
    points = [P(offset_time=i * 10, x=float(p[0]), y=float(p[1]), z=float(p[2]), reflectivity=int(r), tag=0, line=i % 4) for i, (p, r) in enumerate(zip(pts, refl))]
    return T[f"{pkg}/msg/CustomMsg"](header=hdr, timebase=int(stamp * 1e9), point_num=len(points), lidar_id=0, rsvd=np.zeros(3, np.uint8), points=points)


def _pc2_msg(ts, pts, stamp):
    T = ts.types
    PF = T["sensor_msgs/msg/PointField"]
    rec = np.zeros(len(pts), np.dtype({"names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4, "offsets": [0, 4, 8, 16], "itemsize": 32}))
    rec["x"], rec["y"], rec["z"], rec["intensity"] = pts[:, 0], pts[:, 1], pts[:, 2], 7.0
    fields = [PF(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", 8), ("intensity", 16))]
    Time = T["builtin_interfaces/msg/Time"]
    hdr = T["std_msgs/msg/Header"](stamp=Time(sec=int(stamp), nanosec=int((stamp % 1) * 1e9)), frame_id="l")
    return T["sensor_msgs/msg/PointCloud2"](header=hdr, height=1, width=len(pts), fields=fields, is_bigendian=False, point_step=32,
                                            row_step=32 * len(pts), data=np.frombuffer(rec.tobytes(), np.uint8), is_dense=True)  # fmt: skip


def test_ros1_bag_livox_custommsg(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores

    ts = _typestore(Stores.ROS1_NOETIC, "livox_ros_driver")
    rng = np.random.default_rng(0)
    clouds = [rng.uniform(-20, 20, (n, 3)).astype(np.float32) for n in (500, 333)]
    path = tmp_path / "livox.bag"
    with Writer(path) as w:
        conn = w.add_connection("/livox/lidar", "livox_ros_driver/msg/CustomMsg", typestore=ts)
        for k, c in enumerate(clouds):
            msg = _livox_msg(ts, "livox_ros_driver", c, np.arange(len(c)) % 256, 1700000000.0 + 0.1 * k, ros1=True)
            w.write(conn, int((1700000000.0 + 0.1 * k) * 1e9), ts.serialize_ros1(msg, "livox_ros_driver/msg/CustomMsg"))
    got = list(bag_clouds(path))
    assert len(got) == 2
    for g, c in zip(got, clouds):
        np.testing.assert_array_equal(g.points, c)
        np.testing.assert_array_equal(g.intensity, np.arange(len(c)) % 256)
    assert got[0].t == 0.0 and got[1].t == pytest.approx(0.1, abs=1e-6)


@pytest.mark.parametrize("plugin", ["sqlite3", "mcap"])
def test_ros2_bag_custommsg_and_pointcloud2(tmp_path, plugin):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores

    ts = _typestore(Stores.ROS2_HUMBLE, "livox_ros_driver2")
    rng = np.random.default_rng(1)
    c1 = rng.uniform(-20, 20, (257, 3)).astype(np.float32)  # odd count: CDR pads each 19-byte point to 20
    c2 = rng.uniform(-20, 20, (100, 3)).astype(np.float32)
    path = tmp_path / f"bag_{plugin}"
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3 if plugin == "sqlite3" else StoragePlugin.MCAP) as w:
        a = w.add_connection("/livox/lidar", "livox_ros_driver2/msg/CustomMsg", typestore=ts)
        b = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        w.write(a, 10**9, ts.serialize_cdr(_livox_msg(ts, "livox_ros_driver2", c1, np.full(257, 9), 5.0, ros1=False), "livox_ros_driver2/msg/CustomMsg"))
        w.write(b, 2 * 10**9, ts.serialize_cdr(_pc2_msg(ts, c2, 5.5), "sensor_msgs/msg/PointCloud2"))
    got = list(bag_clouds(path, topic="/livox/lidar"))
    assert len(got) == 1
    np.testing.assert_array_equal(got[0].points, c1)
    assert (got[0].intensity == 9).all()
    got = list(bag_clouds(path, topic="/points"))
    np.testing.assert_array_equal(got[0].points, c2)
    assert (got[0].intensity == 7).all()
    both = list(open_clouds(str(path)))
    assert [len(c.points) for c in both] == [257, 100] and both[1].t == pytest.approx(0.5)
    with pytest.raises(InputError, match="no Livox"):
        list(bag_clouds(path, topic="/nope"))


def test_folders_times_and_pairing(tmp_path):
    import cv2

    (tmp_path / "img").mkdir()
    for i in range(4):
        cv2.imwrite(str(tmp_path / "img" / f"{i:06d}.png"), np.full((8, 8, 3), i, np.uint8))
    (tmp_path / "img" / "times.csv").write_text("file,t\n" + "".join(f"{i:06d}.png,{i / 30:.6f}\n" for i in range(4)))
    frames = list(image_folder_frames(tmp_path / "img"))
    assert [f.name for f in frames] == [f"{i:06d}.png" for i in range(4)] and frames[2].load()[0, 0, 0] == 2
    (tmp_path / "cl").mkdir()
    for k, stem in enumerate(["1700000000.000000", "1700000000.050000"]):
        write_pcd(tmp_path / "cl" / f"{stem}.pcd", np.full((3, 3), k, np.float32))
    clouds = list(cloud_folder(tmp_path / "cl"))
    assert [c.t for c in clouds] == pytest.approx([0.0, 0.05])
    pairs = list(merge_by_time(iter(frames), iter(clouds)))
    assert [len(b) for _, b in pairs] == [1, 0, 1, 0]  # cloud at 0.05 waits for the frame at 0.0667
    pairs = list(merge_by_time(iter(frames), iter([CloudFrame(0.01, np.zeros((1, 3)))]), cloud_offset_s=0.05))
    assert [len(b) for _, b in pairs] == [0, 0, 1, 0]
    (tmp_path / "img" / "times.csv").write_text("file,t\n000000.png,abc\n")
    with pytest.raises(InputError, match="times.csv"):
        list(image_folder_frames(tmp_path / "img"))
    with pytest.raises(InputError):
        open_clouds(str(tmp_path / "missing"))


def test_video_file_frames(tmp_path):
    import cv2

    from radarcal.runtime.sources import open_camera

    path = tmp_path / "v.mp4"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (64, 48))
    for i in range(10):
        w.write(np.full((48, 64, 3), 20 * i, np.uint8))
    w.release()
    frames = list(open_camera(str(path)))
    assert len(frames) == 10
    assert [f.t for f in frames] == pytest.approx([i / 25 for i in range(10)], abs=1e-3)
    assert abs(int(frames[5].load().mean()) - 100) < 6
    with pytest.raises(InputError):
        list(open_camera(str(tmp_path / "missing.mp4")))


def test_prefetch_frames_keeps_order_and_errors(tmp_path):
    import cv2

    from radarcal.runtime.sources import CameraFrame, prefetch_frames

    (tmp_path / "img").mkdir()
    for i in range(6):
        cv2.imwrite(str(tmp_path / "img" / f"{i:06d}.png"), np.full((8, 8, 3), i, np.uint8))
    (tmp_path / "img" / "000003.png").write_bytes(b"bad")
    got = list(prefetch_frames(image_folder_frames(tmp_path / "img"), depth=2))
    assert [f.name for f in got] == [f"{i:06d}.png" for i in range(6)]
    assert got[5].load()[0, 0, 0] == 5
    with pytest.raises(InputError):
        got[3].load()

    def slow_live():
        for i in range(20):
            time.sleep(0.005)
            yield CameraFrame(i * 0.005, str(i), lambda i=i: np.full((2, 2), i), i)

    out = []
    for f in prefetch_frames(slow_live(), latest_only=True):
        time.sleep(0.03)  # a slow consumer only ever sees the newest frames
        out.append(int(f.name))
    assert out[-1] == 19 and len(out) < 20 and out == sorted(out)

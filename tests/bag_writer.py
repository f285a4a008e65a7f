"""ROS1 / ROS2 bags of Livox CustomMsg and PointCloud2 clouds written with ``rosbags`` (for the cloud-source tests)."""

from __future__ import annotations

import numpy as np

from radarcal.io.bags import LIVOX_CUSTOM_MSG, LIVOX_CUSTOM_POINT


def typestore(store, pkg):
    from rosbags.typesys import get_types_from_msg, get_typestore

    ts = get_typestore(store)
    ts.register(get_types_from_msg(LIVOX_CUSTOM_POINT, f"{pkg}/msg/CustomPoint"))
    ts.register(get_types_from_msg(LIVOX_CUSTOM_MSG.format(pkg=pkg), f"{pkg}/msg/CustomMsg"))
    return ts


def livox_msg(ts, pkg, pts, refl, stamp, ros1):
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    hdr = T["std_msgs/msg/Header"](seq=1, stamp=Time(sec=int(stamp), nanosec=int(round((stamp % 1) * 1e9))), frame_id="livox") if ros1 else \
        T["std_msgs/msg/Header"](stamp=Time(sec=int(stamp), nanosec=int(round((stamp % 1) * 1e9))), frame_id="livox")  # fmt: skip
    P = T[f"{pkg}/msg/CustomPoint"]
    points = [P(offset_time=i * 10, x=float(p[0]), y=float(p[1]), z=float(p[2]), reflectivity=int(r), tag=0, line=i % 4) for i, (p, r) in enumerate(zip(pts, refl))]
    return T[f"{pkg}/msg/CustomMsg"](header=hdr, timebase=int(stamp * 1e9), point_num=len(points), lidar_id=0, rsvd=np.zeros(3, np.uint8), points=points)


def pc2_msg(ts, pts, stamp, intensity=7.0):
    T = ts.types
    PF = T["sensor_msgs/msg/PointField"]
    rec = np.zeros(len(pts), np.dtype({"names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4, "offsets": [0, 4, 8, 16], "itemsize": 32}))
    rec["x"], rec["y"], rec["z"], rec["intensity"] = pts[:, 0], pts[:, 1], pts[:, 2], intensity
    fields = [PF(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", 8), ("intensity", 16))]
    Time = T["builtin_interfaces/msg/Time"]
    hdr = T["std_msgs/msg/Header"](stamp=Time(sec=int(stamp), nanosec=int(round((stamp % 1) * 1e9))), frame_id="l")
    return T["sensor_msgs/msg/PointCloud2"](header=hdr, height=1, width=len(pts), fields=fields, is_bigendian=False, point_step=32,
                                            row_step=32 * len(pts), data=np.frombuffer(rec.tobytes(), np.uint8), is_dense=True)  # fmt: skip


def write_ros1_livox_bag(path, clouds, stamps, topic="/livox/lidar", refl=None):
    """A ROS1 bag of Livox CustomMsg clouds (``refl``: per-cloud reflectivity arrays, default index % 256)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores

    ts = typestore(Stores.ROS1_NOETIC, "livox_ros_driver")
    with Writer(path) as w:
        conn = w.add_connection(topic, "livox_ros_driver/msg/CustomMsg", typestore=ts)
        for k, (c, st) in enumerate(zip(clouds, stamps)):
            r = refl[k] if refl is not None else np.arange(len(c)) % 256
            msg = livox_msg(ts, "livox_ros_driver", c, r, st, ros1=True)
            w.write(conn, int(round(st * 1e9)), ts.serialize_ros1(msg, "livox_ros_driver/msg/CustomMsg"))
    return path

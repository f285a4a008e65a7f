"""Typed session files: each kind round-trips through the file with its own names, a file of another kind is refused,
and names no command writes are not read (no aliases)."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.bundle import Bundle, load_session, save_bundle, save_session
from radarcal.errors import InputError
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.intrinsics.session import IntrinsicsSession, StereoSession
from radarcal.pnp.session import FieldPnPSession


def test_round_trip_kind_and_no_aliases(tmp_path):
    b = Bundle(path=tmp_path / "b.yaml")
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 1000, (20, 2))
    IntrinsicsSession(corners_uv=uv, residuals=rng.normal(0, 0.2, (20, 2)), camera="cam0", camera_model="fisheye", model="fisheye4", noise_px=0.21,
                      warnings=["w"], board={"cols": 9}).save(b, "intrinsics/cam0")  # fmt: skip
    LidarCameraSession(T_final=np.eye(4), scene_matches={"scene0_uv": uv, "scene1_uv": uv[:3]}, pairs=[["i.png", "c.bag"]], converged=False).save(b, "lidar_camera/cam0_lidar0")
    FieldPnPSession(names=np.array(["a", "b"]), uv=uv[:2], field="rmuc2024", lidar=None).save(b, "field_pnp/cam0")
    StereoSession(T_cam1_cam0=np.eye(4), camera0="l", camera1="r").save(b, "stereo/l_r")
    save_bundle(b, b.path)
    s = IntrinsicsSession.load(b, "intrinsics/cam0")
    np.testing.assert_array_equal(s.corners_uv, uv)
    assert (s.camera, s.camera_model, s.model, s.noise_px, s.warnings, s.board) == ("cam0", "fisheye", "fisheye4", 0.21, ["w"], {"cols": 9})
    assert s.K is None and s.crossval_u is None  # absent stays absent
    arrays, meta = load_session(b, "intrinsics/cam0")
    assert meta["kind"] == "intrinsics" and meta["version"] == 1 and set(arrays) == {"corners_uv", "residuals"}
    lc = LidarCameraSession.load(b, "lidar_camera/cam0_lidar0")
    assert sorted(lc.scene_matches) == ["scene0_uv", "scene1_uv"] and lc.converged is False and lc.pairs == [["i.png", "c.bag"]]
    fp = FieldPnPSession.load(b, "field_pnp/cam0")
    assert list(fp.names) == ["a", "b"] and fp.field == "rmuc2024" and fp.lidar is None
    assert StereoSession.load(b, "stereo/l_r").camera1 == "r"
    with pytest.raises(InputError, match="kind 'intrinsics', expected 'field_pnp'"):
        FieldPnPSession.load(b, "intrinsics/cam0")
    # names no command writes are not read
    save_session(b, "intrinsics/old", {"uv_observed": uv, "corners_uv": uv[:5]}, {"summary": {"noise_px": 0.3}})
    old = IntrinsicsSession.load(b, "intrinsics/old")
    assert len(old.corners_uv) == 5 and old.noise_px is None

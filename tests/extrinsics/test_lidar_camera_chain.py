"""Transforms derived through a stereo pair: stored marked, equal to the chain, replaced by a calibration of the
camera's own, updated / removed when their sources change; the shortest-path helper."""

from __future__ import annotations

import numpy as np

from radarcal import geometry
from radarcal.bundle import Bundle, load_bundle, save_bundle
from radarcal.extrinsics.lidar_camera_chain import chain, is_derived, refresh_derived
from radarcal.synth.two_camera import two_camera_scene


def _bundle(tmp_path, scene):
    b = Bundle(path=tmp_path / "b.yaml")
    for n, c in scene.cameras.items():
        b.set_camera(n, c)
    b.set_sensor("lidar0", type="lidar")
    b.set_transform("cam1", "cam0", scene.T_cam1_cam0, method="intrinsics --right")
    b.set_transform("cam0", "lidar0", scene.T_cam_lidar["cam0"], method="lidar-camera")
    b.set_transform("cam0", "field", scene.T_cam_field("cam0"), method="field-pnp")
    return b


def test_derived_entries_equal_the_chain_and_are_marked(tmp_path):
    sc = two_camera_scene(1, 0)
    b = _bundle(tmp_path, sc)
    changes = refresh_derived(b, "test")
    assert sorted(changes) == ["derived T_cam1_field = T_cam1_cam0 · T_cam0_field", "derived T_cam1_lidar0 = T_cam1_cam0 · T_cam0_lidar0"]
    for x, T_true in (("lidar0", sc.T_cam_lidar["cam1"]), ("field", sc.T_cam_field("cam1"))):
        e = b.transforms[f"T_cam1_{x}"]
        assert is_derived(e) and e.method.startswith("derived:") and e.residual["derived_from"] == ["T_cam1_cam0", f"T_cam0_{x}"]
        deg, m = geometry.pose_error(e.T, T_true)
        assert deg < 1e-9 and m < 1e-9
    save_bundle(b)
    b2 = load_bundle(b.path)
    assert is_derived(b2.transforms["T_cam1_field"]) and refresh_derived(b2) == []  # nothing changed: nothing rewritten


def test_own_calibration_replaces_derived_and_sources_follow(tmp_path):
    sc = two_camera_scene(1, 1)
    b = _bundle(tmp_path, sc)
    refresh_derived(b)
    T_own = geometry.T_from_rotvec(np.radians([0, 0.2, 0]), np.zeros(3)) @ sc.T_cam_lidar["cam1"]
    b.set_transform("cam1", "lidar0", T_own, method="lidar-camera")  # a calibration of cam1's own
    assert refresh_derived(b) == [] and not is_derived(b.transforms["T_cam1_lidar0"])
    np.testing.assert_allclose(b.transforms["T_cam1_lidar0"].T, T_own)
    moved = geometry.T_from_rotvec(np.zeros(3), np.array([0.0, 0.0, 0.05])) @ sc.T_cam_field("cam0")
    b.set_transform("cam0", "field", moved, method="field-pnp")
    assert refresh_derived(b) == ["updated T_cam1_field = T_cam1_cam0 · T_cam0_field"]
    np.testing.assert_allclose(b.transforms["T_cam1_field"].T, sc.T_cam1_cam0 @ moved, atol=1e-12)
    b.transforms.pop("T_cam0_field")
    ch = refresh_derived(b)
    assert len(ch) == 1 and ch[0].startswith("removed T_cam1_field") and "T_cam1_field" not in b.transforms


def test_no_stereo_pair_nothing_derived(tmp_path):
    sc = two_camera_scene(1, 2)
    b = _bundle(tmp_path, sc)
    b.transforms.pop("T_cam1_cam0")
    assert refresh_derived(b) == [] and set(b.transforms) == {"T_cam0_lidar0", "T_cam0_field"}


def test_chain_avoids_frames_and_skips_derived(tmp_path):
    sc = two_camera_scene(1, 3)
    b = _bundle(tmp_path, sc)
    b.transforms.pop("T_cam1_cam0")
    b.set_transform("cam1", "lidar0", sc.T_cam_lidar["cam1"], method="lidar-camera")
    b.set_transform("cam1", "field", sc.T_cam_field("cam1"), method="field-pnp")
    T, names = chain(b, "cam1", "cam0", avoid=("field",))
    assert names == ["T_cam1_lidar0", "T_cam0_lidar0"]
    assert geometry.pose_error(T, sc.T_cam1_cam0)[1] < 1e-9
    b.transforms.pop("T_cam1_lidar0")
    assert chain(b, "cam1", "cam0", avoid=("field",)) is None
    assert chain(b, "cam1", "cam0")[1] == ["T_cam1_field", "T_cam0_field"]

"""The calibration bundle: chaining, validation messages, migration, atomic save, sessions."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml

import radarcal
from radarcal import geometry as g
from radarcal.bundle import (
    SCHEMA_VERSION,
    Bundle,
    Provenance,
    hash_inputs,
    load_bundle,
    load_or_create_bundle,
    load_session,
    save_bundle,
    save_session,
)
from radarcal.camera import Camera
from radarcal.errors import InputError

REPO = Path(__file__).resolve().parents[1]
FIXTURES = Path(__file__).resolve().parent / "fixtures"


def _cam() -> Camera:
    return Camera((1280, 1024), [[863.590518437255, 0.116814496662654, 621.666074631063], [0, 863.100180533059, 533.971978652819], [0, 0, 1]],
                  [-0.0944205499243979, 0.0946727677776504, -0.00807970960613932, 8.07461209775283e-05, 6.52716646875879e-05])


def _bundle() -> Bundle:
    b = Bundle()
    b.set_camera("cam0", _cam(), rms_px=0.1234567891234, sigma={"fx": 0.31, "fy": 0.29}, provenance=Provenance(command="radarcal intrinsics x", inputs_sha256="ab" * 32))
    b.set_sensor("lidar0", type="lidar", model="Livox Mid-70", mount="tripod")
    b.set_sensor("radar_left", type="radar", model="ARS408")
    b.set_transform("cam0", "lidar0", g.T_from_xyz_rpy_deg(0.05, -0.12, 0.03, -90.1, 0.3, -89.7), method="livox-edges", residual={"rms_px": np.float64(1.23), "n": np.int64(812)}, sigma={"rot_deg": 0.05, "trans_m": 0.004})
    b.set_transform("field", "cam0", g.T_from_xyz_rpy_deg(14.0, -1.5, 2.6, -101.0, 0.5, 179.0), method="field-pnp")
    b.set_transform("lidar0", "radar_left", g.T_from_xyz_rpy_deg(0.2, 0.6, -0.1, 0.0, 1.0, 30.0), method="radar-lidar")
    b.field_model = {"name": "rmuc2024", "size": [28.0, 15.0], "landmarks": {"base_red": [1.1, 7.5, 0.0]}}
    b.runtime["hero_range_offset_m"] = 0.35
    return b


# --- T() chaining ------------------------------------------------------------------------------------------------
def test_T_direct_inverse_and_identity():
    b = _bundle()
    T_cam_lidar = b.transforms["T_cam0_lidar0"].T
    np.testing.assert_array_equal(b.T("cam0", "lidar0"), T_cam_lidar)
    np.testing.assert_allclose(b.T("lidar0", "cam0"), np.linalg.inv(T_cam_lidar), atol=1e-12)
    np.testing.assert_array_equal(b.T("cam0", "cam0"), np.eye(4))


def test_T_chains_three_hops_with_inversions():
    b = _bundle()
    T_cam_lidar = b.transforms["T_cam0_lidar0"].T
    T_field_cam = b.transforms["T_field_cam0"].T
    T_lidar_radar = b.transforms["T_lidar0_radar_left"].T
    # field <- cam0 <- lidar0 <- radar_left: three stored edges, all in the forward direction
    np.testing.assert_allclose(b.T("field", "radar_left"), T_field_cam @ T_cam_lidar @ T_lidar_radar, atol=1e-12)
    # the reverse needs three inversions
    np.testing.assert_allclose(b.T("radar_left", "field"), np.linalg.inv(T_lidar_radar) @ np.linalg.inv(T_cam_lidar) @ np.linalg.inv(T_field_cam), atol=1e-12)
    # mixed directions: radar_left -> cam0 goes forward then forward; cam0 -> radar_left inverse twice
    np.testing.assert_allclose(b.T("cam0", "radar_left"), T_cam_lidar @ T_lidar_radar, atol=1e-12)
    # a point really lands where the hand-composed chain says
    p_radar = np.array([[12.0, -3.0, 0.4]])
    p_field = g.transform_points(b.T("field", "radar_left"), p_radar)
    p_by_hand = g.transform_points(T_field_cam, g.transform_points(T_cam_lidar, g.transform_points(T_lidar_radar, p_radar)))
    np.testing.assert_allclose(p_field, p_by_hand, atol=1e-12)


def test_T_four_hops_stored_in_mixed_directions():
    rng = np.random.default_rng(4)
    Ts = {k: g.perturb_T(np.eye(4), rng.uniform(5, 170), rng.uniform(0.1, 5), rng) for k in "abcd"}
    b = Bundle()
    b.set_transform("cam0", "lidar0", Ts["a"])  # T_cam0_lidar0
    b.set_transform("lidar1", "lidar0", Ts["b"])  # T_lidar1_lidar0 (so lidar0 -> lidar1 is forward)
    b.set_transform("radar0", "lidar1", Ts["c"])  # T_radar0_lidar1
    b.set_transform("vehicle", "radar0", Ts["d"])  # T_vehicle_radar0
    expect = Ts["d"] @ Ts["c"] @ Ts["b"] @ np.linalg.inv(Ts["a"])  # T_vehicle_cam0
    np.testing.assert_allclose(b.T("vehicle", "cam0"), expect, atol=1e-10)
    np.testing.assert_allclose(b.T("cam0", "vehicle"), np.linalg.inv(expect), atol=1e-10)
    assert b.has_T("vehicle", "cam0") and not b.has_T("vehicle", "nowhere")


def test_T_missing_link_is_named():
    b = _bundle()
    b.set_sensor("lidar9", type="lidar")
    with pytest.raises(InputError) as e:
        b.T("cam0", "lidar9")
    msg = str(e.value)
    assert "'lidar9'" in msg and "'cam0'" in msg
    assert "lidar0" in msg and "field" in msg  # what cam0 does connect to
    assert "no transform" in msg


def test_set_transform_replaces_reverse_edge_and_rejects_non_rigid():
    b = _bundle()
    T = g.T_from_xyz_rpy_deg(1, 2, 3, 4, 5, 6)
    b.set_transform("lidar0", "cam0", T)
    assert "T_cam0_lidar0" not in b.transforms and "T_lidar0_cam0" in b.transforms
    np.testing.assert_allclose(b.T("cam0", "lidar0"), np.linalg.inv(T), atol=1e-12)
    bad = T.copy()
    bad[:3, :3] *= 1.1
    with pytest.raises(InputError, match=r"transforms\.T_lidar0_cam0\.T: rotation part is not orthonormal"):
        b.set_transform("lidar0", "cam0", bad)
    with pytest.raises(InputError, match=r"transforms\.T_cam0_cam0: needs two different"):
        b.set_transform("cam0", "cam0", T)


def test_camera_lookup():
    b = _bundle()
    assert b.camera("cam0") is b.cameras["cam0"].camera
    with pytest.raises(InputError, match=r"no camera 'cam7' in the bundle \(cameras: cam0\)"):
        b.camera("cam7")


# --- save / load -------------------------------------------------------------------------------------------------
def test_save_load_round_trip_is_exact(tmp_path):
    b = _bundle()
    path = save_bundle(b, tmp_path / "rig.yaml")
    back = load_bundle(path)
    assert back.to_dict() == b.to_dict()
    e0, e1 = b.cameras["cam0"], back.cameras["cam0"]
    assert np.array_equal(e0.camera.K, e1.camera.K) and np.array_equal(e0.camera.dist, e1.camera.dist)
    assert e1.rms_px == 0.1234567891234 and e1.sigma == {"fx": 0.31, "fy": 0.29}
    assert e1.provenance == e0.provenance and e1.provenance.radarcal_version == radarcal.__version__
    for k, t in b.transforms.items():
        assert np.array_equal(back.transforms[k].T, t.T)  # bit-exact floats
        assert back.transforms[k].method == t.method
    assert back.transforms["T_cam0_lidar0"].residual == {"rms_px": 1.23, "n": 812}
    assert back.sensors["lidar0"] == {"type": "lidar", "model": "Livox Mid-70", "mount": "tripod"}
    assert back.sensors["cam0"] == {"type": "camera"}
    assert back.field_model == b.field_model and back.runtime == b.runtime
    assert back.path == path
    # a second save of what was loaded is byte-identical apart from nothing: the text is stable
    assert back.dumps() == b.dumps()
    text = path.read_text()
    assert text.startswith("# radarcal calibration bundle") and "schema_version: 1" in text


def test_save_keeps_previous_as_backup(tmp_path):
    path = tmp_path / "rig.yaml"
    b = _bundle()
    save_bundle(b, path)
    assert list(tmp_path.glob("*.bak")) == []
    first = path.read_bytes()
    b.runtime["hero_range_offset_m"] = 0.5
    save_bundle(b, path)
    baks = sorted(tmp_path.glob("rig.yaml.*.bak"))
    assert len(baks) == 1 and baks[0].read_bytes() == first
    assert load_bundle(path).runtime["hero_range_offset_m"] == 0.5
    assert load_bundle(baks[0]).runtime["hero_range_offset_m"] == 0.35
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_backups_are_bounded(tmp_path):
    from radarcal.bundle import BACKUPS_KEPT

    path = tmp_path / "rig.yaml"
    b = _bundle()
    for i in range(BACKUPS_KEPT + 4):
        b.runtime["cloud_queue_points"] = 1000 + i
        save_bundle(b, path)
    baks = sorted(tmp_path.glob("rig.yaml.*.bak"))
    assert len(baks) == BACKUPS_KEPT
    # the newest backup is the save before the last one
    assert load_bundle(baks[-1]).runtime["cloud_queue_points"] == 1000 + BACKUPS_KEPT + 2


def test_save_refuses_invalid_bundle_and_leaves_file(tmp_path):
    path = tmp_path / "rig.yaml"
    b = _bundle()
    save_bundle(b, path)
    before = path.read_bytes()
    b.runtime["hero_range_offset_m"] = float("nan")
    with pytest.raises(InputError, match="hero_range_offset_m"):
        save_bundle(b, path)
    assert path.read_bytes() == before


CRASH_CHILD = textwrap.dedent(
    """
    import os, signal, sys
    sys.path.insert(0, sys.argv[2])
    from radarcal import bundle as rb
    b = rb.load_bundle(sys.argv[1])
    b.runtime["hero_range_offset_m"] = 9.75
    b.cameras["cam0"].rms_px = 7.0

    def crash(src, dst):
        # the new bundle has been written to the temp file and fsynced: die before the rename
        with open(src, "rb") as f:
            assert b"9.75" in f.read()
        os.kill(os.getpid(), signal.SIGKILL)

    rb.os.replace = crash
    rb.save_bundle(b, sys.argv[1])
    print("not reached")
    """
)


def test_atomic_save_survives_kill_between_write_and_rename(tmp_path):
    path = tmp_path / "rig.yaml"
    save_bundle(_bundle(), path)
    before = path.read_bytes()
    proc = subprocess.run([sys.executable, "-c", CRASH_CHILD, str(path), str(REPO)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -9, proc.stderr  # SIGKILLed
    assert "not reached" not in proc.stdout
    assert path.read_bytes() == before
    b = load_bundle(path)
    assert b.runtime["hero_range_offset_m"] == 0.35 and b.cameras["cam0"].rms_px == 0.1234567891234
    # the orphaned temp file holds the new content; it never replaced the bundle
    tmps = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert len(tmps) == 1 and b"9.75" in tmps[0].read_bytes()
    # the next normal save still works next to the orphan
    b.runtime["hero_range_offset_m"] = 1.0
    save_bundle(b, path)
    assert load_bundle(path).runtime["hero_range_offset_m"] == 1.0


def test_save_to_unwritable_place_is_an_input_error(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="cannot write bundle"):
        save_bundle(_bundle(), tmp_path / "file" / "rig.yaml")


def test_load_or_create(tmp_path):
    b = load_or_create_bundle(tmp_path / "new.yaml")
    assert b.cameras == {} and b.path == tmp_path / "new.yaml" and not (tmp_path / "new.yaml").exists()
    save_bundle(_bundle(), tmp_path / "old.yaml")
    assert "cam0" in load_or_create_bundle(tmp_path / "old.yaml").cameras


# --- loader rejections -------------------------------------------------------------------------------------------
def _write(tmp_path, mutate) -> Path:
    d = yaml.safe_load(_bundle().dumps())
    mutate(d)
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return p


def _set(path: str, value):
    def mutate(d):
        keys = path.split(".")
        node = d
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value

    return mutate


REJECTIONS = [
    ("cameras.cam0.K", [[800, 0, 640], [0, 800, 512], [0, 0]], r"cameras\.cam0\.K: expected 3x3, got 3x2|cameras\.cam0\.K: expected a 3x3"),
    ("cameras.cam0.K", [[800, 0], [0, 800], [0, 0]], r"^.*bad\.yaml: cameras\.cam0\.K: expected 3x3, got 3x2$"),
    ("cameras.cam0.K", [[800, 0, 640], [0, float("nan"), 512], [0, 0, 1]], r"cameras\.cam0\.K: non-finite value"),
    ("cameras.cam0.K", [[-800, 0, 640], [0, 800, 512], [0, 0, 1]], r"cameras\.cam0\.K: focal lengths must be positive, got fx=-800"),
    ("cameras.cam0.K", [[800, 0, 640], [0, 800, 512], [0, 0, 2]], r"cameras\.cam0\.K: expected \[\[fx, s, cx\], \[0, fy, cy\], \[0, 0, 1\]\]"),
    ("cameras.cam0.K", "eight hundred", r"cameras\.cam0\.K: expected a 3x3 matrix of numbers"),
    ("cameras.cam0.dist", [0.1, float("inf"), 0, 0, 0], r"cameras\.cam0\.dist: non-finite value"),
    ("cameras.cam0.dist", [0.1, 0.2, 0.0], r"cameras\.cam0\.dist: pinhole needs 4/5/8/12 coefficients, got 3"),
    ("cameras.cam0.dist", ["a", "b", "c", "d"], r"cameras\.cam0\.dist: expected a list of numbers"),
    ("cameras.cam0.model", "kannala_brandt", r"cameras\.cam0\.model: expected one of"),
    ("cameras.cam0.image_size", [1280], r"cameras\.cam0\.image_size: expected \[width, height\]"),
    ("cameras.cam0.image_size", [1280, -5], r"cameras\.cam0\.image_size: expected \[width, height\]"),
    ("cameras.cam0.image_size", ["wide", "tall"], r"cameras\.cam0\.image_size: expected \[width, height\]"),
    ("cameras.cam0.rms_px", -1.0, r"cameras\.cam0\.rms_px: expected a non-negative number"),
    ("cameras.cam0.sigma", [1, 2], r"cameras\.cam0\.sigma: expected a mapping"),
    ("cameras.cam0", [1, 2], r"cameras\.cam0: expected a mapping, got list"),
    ("transforms.T_cam0_lidar0.T", (np.eye(4) * [1.01, 1, 1, 1]).tolist(), r"transforms\.T_cam0_lidar0\.T: rotation part is not orthonormal"),
    ("transforms.T_cam0_lidar0.T", np.diag([1.0, 1.0, -1.0, 1.0]).tolist(), r"transforms\.T_cam0_lidar0\.T: rotation part is not orthonormal with det \+1"),
    ("transforms.T_cam0_lidar0.T", [[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], r"transforms\.T_cam0_lidar0\.T: non-finite value"),
    ("transforms.T_cam0_lidar0.T", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], r"transforms\.T_cam0_lidar0\.T: expected 4x4, got 3x4"),
    ("transforms.T_cam0_lidar0.T", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.1, 1]], r"transforms\.T_cam0_lidar0\.T: last row must be \[0, 0, 0, 1\]"),
    ("transforms.T_cam0_lidar0.source", "lidar1", r"transforms\.T_cam0_lidar0: key does not match target/source"),
    ("transforms.T_cam0_lidar0.target", None, r"transforms\.T_cam0_lidar0: needs 'target' and 'source'"),
    ("transforms.T_cam0_lidar0.residual", "tiny", r"transforms\.T_cam0_lidar0\.residual: expected a mapping"),
    ("runtime.hero_range_offset_m", float("inf"), r"runtime\.hero_range_offset_m: expected a finite number"),
    ("runtime", [1], r"runtime: expected a mapping"),
    ("schema_version", SCHEMA_VERSION + 1, rf"schema_version {SCHEMA_VERSION + 1} is newer than this radarcal understands \({SCHEMA_VERSION}\); upgrade radarcal"),
    ("schema_version", "one", r"schema_version: expected an integer, got 'one'"),
]


@pytest.mark.parametrize("where, value, pattern", REJECTIONS, ids=[f"{w}={v!r}"[:60] for w, v, _ in REJECTIONS])
def test_loader_rejections(tmp_path, where, value, pattern):
    p = _write(tmp_path, _set(where, value))
    with pytest.raises(InputError) as e:
        load_bundle(p)
    assert e.value.source == str(p)
    assert __import__("re").search(pattern, str(e.value)), str(e.value)
    assert "\n" not in str(e.value)


def test_rejects_K_3x2_with_the_exact_message(tmp_path):
    p = _write(tmp_path, _set("cameras.cam0.K", [[800, 0], [0, 800], [0, 0]]))
    with pytest.raises(InputError) as e:
        load_bundle(p)
    assert e.value.message == "cameras.cam0.K: expected 3x3, got 3x2"


def test_rejects_non_finite_written_as_yaml_nan(tmp_path):
    """Non-finite numbers as a person would type them in YAML (.nan / .inf)."""
    text = _bundle().dumps()
    p = tmp_path / "nan.yaml"
    p.write_text(text.replace("hero_range_offset_m: 0.35", "hero_range_offset_m: .inf"))
    with pytest.raises(InputError, match=r"runtime\.hero_range_offset_m: expected a finite number"):
        load_bundle(p)
    d = yaml.safe_load(text)
    row = d["transforms"]["T_cam0_lidar0"]["T"][0]
    p.write_text(text.replace(f"[{row[0]}, {row[1]}, {row[2]}, {row[3]}]", f"[{row[0]}, {row[1]}, {row[2]}, .nan]"))
    with pytest.raises(InputError, match=r"transforms\.T_cam0_lidar0\.T: non-finite value"):
        load_bundle(p)


def test_bad_yaml_names_the_line(tmp_path):
    p = tmp_path / "broken.yaml"
    lines = _bundle().dumps().splitlines()
    lines[5] = lines[5] + " ]]: {"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        load_bundle(p)
    assert e.value.source == str(p)
    assert e.value.message.startswith("not valid YAML/JSON at line ")
    line = int(e.value.message.split("line ")[1].split()[0])
    assert 5 <= line <= 7


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(InputError) as e:
        load_bundle(tmp_path / "nope.yaml")
    assert str(e.value) == f"{tmp_path / 'nope.yaml'}: bundle not found"
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00garbage\x81")
    with pytest.raises(InputError, match="cannot read bundle"):
        load_bundle(tmp_path / "bin.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="top level is not a mapping"):
        load_bundle(tmp_path / "list.yaml")
    (tmp_path / "empty.yaml").write_text("")
    with pytest.raises(InputError, match="top level is not a mapping"):
        load_bundle(tmp_path / "empty.yaml")
    with pytest.raises(InputError, match="is a directory|cannot read bundle"):
        load_bundle(tmp_path)


def test_json_bundle_loads(tmp_path):
    import json

    b = _bundle()  # one bundle: provenance times are stamped at creation, two calls can straddle a second
    p = tmp_path / "rig.json"
    p.write_text(json.dumps(yaml.safe_load(b.dumps())))
    assert load_bundle(p).to_dict() == b.to_dict()


# --- migration ---------------------------------------------------------------------------------------------------
def test_migrate_v0_fixture_field_by_field(tmp_path):
    src = FIXTURES / "bundle_v0.yaml"
    b = load_bundle(src)
    c0 = b.cameras["cam0"]
    assert c0.camera.model == "pinhole" and c0.camera.image_size == (1920, 1080)
    np.testing.assert_array_equal(c0.camera.K, [[1364.45, 0, 958.327], [0, 1366.46, 535.074], [0, 0, 1]])
    np.testing.assert_array_equal(c0.camera.dist, [-0.0843, 0.1362, 0.00021, -0.00043, -0.0381])
    assert c0.rms_px == 0.231 and c0.provenance.command == "migrated from schema v0"
    c1 = b.cameras["cam1"]
    assert c1.camera.model == "fisheye" and c1.camera.image_size == (1280, 1024) and c1.rms_px is None
    np.testing.assert_array_equal(c1.camera.K, [[410.5, 0, 640.0], [0, 410.25, 512.0], [0, 0, 1]])
    np.testing.assert_array_equal(c1.camera.dist, [0.021, -0.0043, 0.0011, -0.0002])
    # "lidar0->cam0" maps points in lidar0 into cam0: T_cam0_lidar0
    assert set(b.transforms) == {"T_cam0_lidar0", "T_field_cam0"}
    t = b.transforms["T_cam0_lidar0"]
    assert (t.target, t.source) == ("cam0", "lidar0")
    np.testing.assert_array_equal(t.T, [[0, -1, 0, 0.05], [0, 0, -1, -0.12], [1, 0, 0, 0.03], [0, 0, 0, 1]])
    assert t.method == "migrated from schema v0"
    np.testing.assert_array_equal(b.transforms["T_field_cam0"].T, [[1, 0, 0, 14.0], [0, 0, 1, -1.5], [0, -1, 0, 2.6], [0, 0, 0, 1]])
    # the point 10 m ahead of the LiDAR is 10 m along the camera's optical axis
    np.testing.assert_allclose(g.transform_points(b.T("cam0", "lidar0"), [[10.0, 0, 0]]), [[0.05, -0.12, 10.03]])
    assert b.runtime["hero_range_offset_m"] == 0.35
    assert b.runtime["cloud_queue_points"] == radarcal.bundle.DEFAULT_RUNTIME["cloud_queue_points"]
    assert b.field_model == {"name": "rmuc2024", "size": [28.0, 15.0]}
    assert b.sessions == {}
    # saving writes the current schema; loading that gives the same bundle
    out = save_bundle(b, tmp_path / "migrated.yaml")
    d = yaml.safe_load(out.read_text())
    assert d["schema_version"] == SCHEMA_VERSION and "version" not in d and "extrinsics" not in d
    assert load_bundle(out).to_dict() == b.to_dict()


def test_migrate_v0_missing_field_is_reported(tmp_path):
    d = yaml.safe_load((FIXTURES / "bundle_v0.yaml").read_text())
    del d["cameras"]["cam0"]["fx"]
    p = tmp_path / "v0.yaml"
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=r"cannot migrate schema v0: .*fx"):
        load_bundle(p)


# --- provenance / sessions ---------------------------------------------------------------------------------------
def test_hash_inputs(tmp_path):
    a, b2 = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_bytes(b"one")
    b2.write_bytes(b"two")
    h = hash_inputs([a, b2], extra={"opt": 1})
    assert len(h) == 64 and h == hash_inputs([a, b2], extra={"opt": 1})
    assert h != hash_inputs([b2, a], extra={"opt": 1}) and h != hash_inputs([a, b2], extra={"opt": 2})
    a.write_bytes(b"ONE")
    assert h != hash_inputs([a, b2], extra={"opt": 1})


def test_session_round_trip(tmp_path):
    path = tmp_path / "rig.yaml"
    b = _bundle()
    save_bundle(b, path)
    rng = np.random.default_rng(0)
    arrays = {"uv": rng.normal(size=(40, 2)), "ids": np.arange(40, dtype=np.int32), "rvecs": rng.normal(size=(5, 3))}
    written = save_session(b, "intrinsics/cam0", arrays, meta={"board": "9x6", "rms": np.float64(0.4)})
    save_bundle(b, path)
    assert written.is_file() and written.parent == tmp_path / "rig.sessions"
    again = load_bundle(path)
    assert again.sessions == {"intrinsics/cam0": "rig.sessions/intrinsics__cam0.npz"}
    got, meta = load_session(again, "intrinsics/cam0")
    assert set(got) == set(arrays)
    for k in arrays:
        assert np.array_equal(got[k], arrays[k]) and got[k].dtype == arrays[k].dtype
    assert meta == {"board": "9x6", "rms": 0.4}
    with pytest.raises(InputError, match=r"no session 'extrinsics/cam0' in the bundle \(sessions: intrinsics/cam0\)"):
        load_session(again, "extrinsics/cam0")
    written.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(InputError, match="cannot read session file"):
        load_session(again, "intrinsics/cam0")
    written.unlink()
    with pytest.raises(InputError, match="session file not found"):
        load_session(again, "intrinsics/cam0")


def test_field_accessor_parses_once_and_runtime_defaults_have_one_source(tmp_path):
    import dataclasses

    from radarcal.bundle import Bundle
    from radarcal.errors import InputError
    from radarcal.field import builtin_field
    from radarcal.runtime.config import RunConfig

    b = Bundle(path=tmp_path / "b.yaml")
    assert b.field() is None
    b.field_model = builtin_field("rmuc2024").to_dict()
    fm = b.field()
    assert fm is b.field() and fm.name == "rmuc_schematic" and "blue_outpost" in fm.landmarks  # parsed once
    b.field_model = {**b.field_model, "name": "edited"}
    assert b.field().name == "edited"  # a new dict is parsed again
    b.field_model = {"name": "broken"}
    with pytest.raises(InputError, match="b.yaml: field"):
        b.field()
    # DEFAULT_RUNTIME is derived from RunConfig's defaults; from_bundle reads what the bundle stores over them
    defaults = {f.name: f.default for f in dataclasses.fields(RunConfig)}
    assert radarcal.bundle.DEFAULT_RUNTIME == {"hero_range_offset_m": defaults["hero_range_offset_m"], "cloud_queue_points": defaults["cloud_queue_points"],
                                               "cloud_queue_age_s": defaults["cloud_queue_age_s"], "referee_season": defaults["season"]}  # fmt: skip
    b.runtime = {"referee_season": "2025", "sentry_xy": [3, 4, 0], "team": "blue", "cloud_queue_points": 5}
    cfg = RunConfig.from_bundle(b, team=None, robot_radius_m=0.3)
    assert (cfg.season, cfg.sentry_xy, cfg.team, cfg.cloud_queue_points, cfg.robot_radius_m, cfg.depth_max_age_s) == (2025, (3.0, 4.0), "blue", 5, 0.3, defaults["depth_max_age_s"])

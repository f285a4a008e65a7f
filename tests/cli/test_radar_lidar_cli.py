"""``radarcal synth radar`` + ``radarcal radar-lidar``: end to end through the CLI into a bundle, errors as one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle, load_session
from radarcal.cli.main import main


def test_synth_then_calibrate_into_bundle(tmp_path, capsys):
    ses = tmp_path / "session"
    assert main(["synth", "radar", str(ses), "--seed", "5", "--sigma", "0.01", "--frames", "20", "--ghosts", "0.5", "--p-miss", "0.1",
                 "--extra-lidars", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["radars"] == ["radar_left", "radar_middle", "radar_right"] and out["lidars"] == ["lidar_front", "lidar_left"]
    bundle = tmp_path / "b.yaml"
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    truth = json.loads((ses / "truth.json").read_text())
    b = load_bundle(bundle)
    for r in ("radar_left", "radar_middle", "radar_right"):
        e = b.transforms[f"T_lidar_front_{r}"]
        deg, m = geometry.pose_error(e.T, np.array(truth["T_main_sensor"][r]))
        # 20 averaged frames at 1 cm: ~0.2 cm per reflector; the ground plane from a 5 mm-noise cloud sets roll/pitch
        assert deg < 0.3 and m < 0.01, (r, deg, m)
        assert e.residual["rms_m"] < 0.02 and e.residual["n"] >= 4
        assert e.sigma["yaw_deg"] > 0 and "x_m" in e.sigma
        assert e.provenance.command.startswith("radarcal") and len(e.provenance.inputs_sha256) == 64
        assert b.sensors[r]["mount_height_m"] == truth["radar_mount_height_m"][r]
        assert s["radars"][r]["per_reflector"]
    e = b.transforms["T_lidar_front_lidar_left"]
    deg, m = geometry.pose_error(e.T, np.array(truth["T_main_sensor"]["lidar_left"]))
    assert deg < 0.1 and m < 0.01 and e.residual["fitness"] > e.residual["initial_fitness"]
    assert "T_vehicle_lidar_front" in b.transforms
    np.testing.assert_allclose(b.T("vehicle", "radar_middle"), truth["T_vehicle_sensor"]["radar_middle"], atol=0.01)
    arrays, meta = load_session(b, "radar_lidar")
    assert meta["model"] == "slant" and set(meta["filter_counts"]) == {"00", "01", "02", "03"}
    assert any(k.endswith("/residual_m") for k in arrays)
    assert all(c["B"] >= 2 for c in s["filter_counts"].values())


def test_human_output_and_quantised_lists(tmp_path, capsys):
    ses = tmp_path / "q"
    assert main(["synth", "radar", str(ses), "--seed", "2", "--sigma", "0.02", "--quantise", "0.2", "--frames", "10", "--ghosts", "0"]) == 0
    capsys.readouterr()
    assert main(["radar-lidar", str(ses), "--bundle", str(tmp_path / "b.yaml")]) == 0
    text = capsys.readouterr().out
    assert "T_lidar_front_radar_middle" in text and "A=" in text and "0.2 m grid" in text and "averaging frames cannot remove" in text


@pytest.mark.parametrize("break_it, expect", [
    (lambda d: (d / "rig.yaml").write_text("radars: [\n"), "rig.yaml: not valid YAML"),
    (lambda d: (d / "scenes" / "00" / "radar.csv").write_text("radar,x,y\nradar_left,1,x\n"), "radar.csv: line 2: y 'x' is not a number"),
    (lambda d: (d / "scenes" / "00" / "lidar_front.pcd").unlink(), "no cloud for the main LiDAR"),
])
def test_bad_input_one_line_exit_2(tmp_path, capsys, break_it, expect):
    ses = tmp_path / "s"
    tmp_path.mkdir(parents=True, exist_ok=True)  # synth writes into an existing folder
    assert main(["synth", "radar", str(ses), "--scenes", "1", "--seed", "1"]) == 0
    break_it(ses)
    capsys.readouterr()
    bundle = tmp_path / "b.yaml"
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and expect in err and len(err.strip().splitlines()) == 1
    assert not bundle.exists()  # nothing half-written


# --- issue 18: bad sessions, refusals, the real data sets through the command as shipped --------------------------------
def _one_scene(tmp_path, extra=()):
    ses = tmp_path / "s"
    tmp_path.mkdir(parents=True, exist_ok=True)  # synth writes into an existing folder
    assert main(["synth", "radar", str(ses), "--scenes", "2", "--seed", "4", *extra]) == 0
    return ses


def _no_reflector(d):
    from radarcal.io import read_cloud
    from radarcal.io.clouds import write_pcd

    p = d / "scenes" / "00" / "lidar_front.pcd"
    pts = read_cloud(p).points
    write_pcd(p, pts[np.linalg.norm(pts, axis=1) > 6.0])  # only what lies beyond the reflectors: ground, boxes, walls


def _one_detection(d):
    for k in ("00", "01"):
        rows = (d / "scenes" / k / "radar.csv").read_text().splitlines()
        keep = [r for r in rows if not r.startswith("radar_left")]
        if k == "00":
            keep.append(next(r for r in rows if r.startswith("radar_left")))
        (d / "scenes" / k / "radar.csv").write_text("\n".join(keep) + "\n")


@pytest.mark.parametrize("break_it, expect, extra", [
    (_no_reflector, "no reflector seen within 4 m", ()),
    (_one_detection, "radar 'radar_left': 1 detection in all scenes", ()),
    (lambda d: (d / "scenes" / "01" / "lidar_left.pcd").unlink(), "lidar_left.pcd: cloud of LiDAR 'lidar_left' missing in this scene", ("--extra-lidars", "1")),
])
def test_bad_sessions_one_line_exit_2_bundle_intact(tmp_path, capsys, break_it, expect, extra):
    ses = _one_scene(tmp_path, extra)
    break_it(ses)
    bundle = tmp_path / "b.yaml"
    ok = _one_scene(tmp_path / "ok")  # an existing bundle that a failed command must leave alone
    assert main(["radar-lidar", str(ok), "--bundle", str(bundle)]) == 0
    before = bundle.read_bytes()
    capsys.readouterr()
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and expect in err and len(err.strip().splitlines()) == 1, err
    assert bundle.read_bytes() == before


@pytest.mark.slow
def test_unobserved_second_lidar_refused_nothing_stored(tmp_path, capsys):
    from radarcal.synth.radar import (
        feature_spec,
        generate_radar_session,
        write_radar_session,
    )

    spec = feature_spec(7, "check")
    spec.n_scenes = 2
    ses = write_radar_session(generate_radar_session(spec), tmp_path / "s")
    bundle = tmp_path / "b.yaml"
    capsys.readouterr()
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle), "--json"]) == 1
    s = json.loads(capsys.readouterr().out)
    assert not s["stored"] and not bundle.exists()
    (why,) = [w for w in s["refusals"] if w.startswith("lidar_left: ")]
    assert "is not observed" in why and "lidar_front" in why  # the direction is named
    assert s["lidars"]["lidar_left"]["reflector_pairs"] == 0  # its 70 deg field of view misses the reflectors
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle), "--force", "--json"]) == 0 and bundle.exists()


def test_ars408_object_lists_through_the_command(tmp_path, capsys):
    ses = tmp_path / "a"
    assert main(["synth", "radar", str(ses), "--seed", "3", "--frames", "3", "--sigma", "0.01", "--radar-format", "ars408"]) == 0
    assert (ses / "scenes" / "00" / "radar_middle.csv").is_file() and not (ses / "scenes" / "00" / "radar.csv").exists()
    capsys.readouterr()
    assert main(["radar-lidar", str(ses), "--bundle", str(tmp_path / "b.yaml"), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    truth = json.loads((ses / "truth.json").read_text())
    for r, d in s["radars"].items():
        deg, m = geometry.pose_error(np.array(d["T_main_radar"]), np.array(truth["T_main_sensor"][r]))
        assert deg < 0.5 and m < 0.02, (r, deg, m)


def test_tudelft_example_as_shipped(shared, tmp_path, capsys):
    root = shared("tudelft_msc_example") / "optimization_example_data"
    assert main(["radar-lidar", str(root), "--bundle", str(tmp_path / "b.yaml"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["radars"]["radar"]
    # docs/radar_lidar.md: slant + radar height, 1.19 cm RMS on the 29, yaw -90.964 deg (radar from LiDAR), |dz| 0.40 m
    assert d["residual"]["rms_m"] == pytest.approx(0.0119, abs=0.0005) and d["residual"]["n"] == 29
    assert d["rpy_deg"][2] == pytest.approx(90.964, abs=0.05)
    assert d["mount_height_m"] == pytest.approx(-0.505, abs=0.02)


@pytest.mark.slow
def test_opencalib_lidar2lidar_as_shipped(shared, tmp_path, capsys):
    root = shared("opencalib_lidar2lidar_0001")
    assert main(["radar-lidar", str(root), "--bundle", str(tmp_path / "a.yaml"), "--json"]) == 1  # the default 2 cm check refuses
    s = json.loads(capsys.readouterr().out)
    assert not s["stored"] and any("is not observed" in w for w in s["refusals"]) and not (tmp_path / "a.yaml").exists()
    assert main(["radar-lidar", str(root), "--bundle", str(tmp_path / "b.yaml"), "--lidar-tolerance", "0.5,0.05", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["stored"] and not s["refusals"]
    # docs/radar_lidar.md: fitness at 0.3 m 0.012 -> 0.426 (left), 0.007 -> 0.449 (right), inlier RMSE -> 0.149 m
    for n, f0, f1 in (("left", 0.012, 0.426), ("right", 0.007, 0.449)):
        d = s["lidars"][n]
        assert d["initial_fitness"] == pytest.approx(f0, abs=0.002) and d["fitness"] == pytest.approx(f1, abs=0.01)
        assert d["inlier_rmse_m"] == pytest.approx(0.149, abs=0.005)


def test_reflector_centres_session_tudelft_style(tmp_path, capsys):
    """scenes/<k>/reflectors.csv instead of a cloud (a level main LiDAR; radar heights unknown: estimated)."""
    import yaml

    from radarcal.synth.radar import RadarRigSpec, RadarSceneSpec, generate_radar_session, write_radar_session

    spec = RadarSceneSpec(rig=RadarRigSpec(main_lidar_pose=(2.2, 0.0, 1.35, 0.0, 0.0, 0.8)), n_scenes=4, radar_sigma=0.0, lidar_noise=0.0, seed=9)
    ses = generate_radar_session(spec)
    root = write_radar_session(ses, tmp_path / "c")
    rig = yaml.safe_load((root / "rig.yaml").read_text())
    for r in rig["radars"].values():
        r.pop("mount_height_m")
    (root / "rig.yaml").write_text(yaml.safe_dump(rig))
    for sc in ses.truth["scenes"]:
        d = root / "scenes" / sc["name"]
        (d / "lidar_front.pcd").unlink()
        (d / "reflectors.csv").write_text("lidar,x,y,z\n" + "".join(f"lidar_front,{x},{y},{z}\n" for x, y, z in sc["apex_main"]))
    capsys.readouterr()
    assert main(["radar-lidar", str(root), "--bundle", str(tmp_path / "b.yaml"), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert sum("estimated from the slant model" in n for n in s["notes"]) == 3
    for r, d in s["radars"].items():
        T, T_true = np.array(d["T_main_radar"]), np.array(ses.truth["T_main_sensor"][r])
        yaw = np.degrees(np.arctan2((T_true[:3, :3].T @ T[:3, :3])[1, 0], (T_true[:3, :3].T @ T[:3, :3])[0, 0]))
        assert abs(yaw) < 1e-4 and np.linalg.norm(T[:2, 3] - T_true[:2, 3]) < 1e-4, (r, yaw, T[:3, 3], T_true[:3, 3])


def _scenes_as_bags(ses):
    """Every scene's LiDAR clouds recorded instead as bags written by rosbags: the main LiDAR as a ROS1 bag of four
    Livox CustomMsg clouds, the second as a ROS2 (mcap) bag folder of three PointCloud2 clouds plus an IMU-less
    decoy cloud topic, so that ``--cloud-topic`` must choose. Reflectivity / intensity constant (the PCDs carry none)."""
    from bag_writer import pc2_msg, typestore, write_ros1_livox_bag
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores

    from radarcal.io import read_cloud

    ts = typestore(Stores.ROS2_HUMBLE, "livox_ros_driver2")
    for d in sorted((ses / "scenes").iterdir()):
        pts = read_cloud(d / "lidar_front.pcd").points
        parts = np.array_split(np.arange(len(pts)), 4)
        write_ros1_livox_bag(d / "lidar_front.bag", [pts[i] for i in parts], [1700000000.0 + 0.1 * k for k in range(4)],
                             refl=[np.full(len(i), 40) for i in parts])
        (d / "lidar_front.pcd").unlink()
        pts = read_cloud(d / "lidar_left.pcd").points
        with Writer(d / "lidar_left", version=9, storage_plugin=StoragePlugin.MCAP) as w:
            a = w.add_connection("/livox/lidar", "sensor_msgs/msg/PointCloud2", typestore=ts)
            b = w.add_connection("/decoy", "sensor_msgs/msg/PointCloud2", typestore=ts)
            for k, i in enumerate(np.array_split(np.arange(len(pts)), 3)):
                w.write(a, (k + 1) * 10**8, ts.serialize_cdr(pc2_msg(ts, pts[i], 0.1 * (k + 1)), "sensor_msgs/msg/PointCloud2"))
            w.write(b, 10**9, ts.serialize_cdr(pc2_msg(ts, pts[:10] + 50.0, 1.0), "sensor_msgs/msg/PointCloud2"))
        (d / "lidar_left.pcd").unlink()


def test_radar_lidar_reads_the_clouds_from_ros_bags(tmp_path, capsys):
    """The session of the first test with its clouds in ROS1 / ROS2 bags: the same truth figures; the bag with two
    cloud topics needs --cloud-topic (one line, exit 2, nothing written); the bag files are in the provenance."""
    ses = tmp_path / "session"
    assert main(["synth", "radar", str(ses), "--seed", "5", "--sigma", "0.01", "--frames", "20", "--ghosts", "0.5", "--p-miss", "0.1",
                 "--extra-lidars", "1", "--scenes", "2"]) == 0
    _scenes_as_bags(ses)
    bundle = tmp_path / "b.yaml"
    capsys.readouterr()
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "lidar_left: several cloud topics (/decoy, /livox/lidar): choose one with --cloud-topic" in err, err
    assert len(err.strip().splitlines()) == 1 and not bundle.exists()
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle), "--cloud-topic", "/livox/lidar", "--json"]) == 0
    capsys.readouterr()
    truth = json.loads((ses / "truth.json").read_text())
    b = load_bundle(bundle)
    for r in ("radar_left", "radar_middle", "radar_right"):
        deg, m = geometry.pose_error(b.transforms[f"T_lidar_front_{r}"].T, np.array(truth["T_main_sensor"][r]))
        assert deg < 0.3 and m < 0.01, (r, deg, m)
    deg, m = geometry.pose_error(b.transforms["T_lidar_front_lidar_left"].T, np.array(truth["T_main_sensor"]["lidar_left"]))
    assert deg < 0.1 and m < 0.01
    from radarcal.io.radar import read_radar_session

    files = read_radar_session(ses, "/livox/lidar").input_files()
    assert any(f.name == "lidar_front.bag" for f in files) and any(f.suffix == ".mcap" for f in files)

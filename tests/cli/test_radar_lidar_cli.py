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
    assert main(["synth", "radar", str(ses), "--scenes", "1", "--seed", "1"]) == 0
    break_it(ses)
    capsys.readouterr()
    bundle = tmp_path / "b.yaml"
    assert main(["radar-lidar", str(ses), "--bundle", str(bundle)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and expect in err and len(err.strip().splitlines()) == 1
    assert not bundle.exists()  # nothing half-written

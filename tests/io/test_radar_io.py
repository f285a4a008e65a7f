"""Radar readers: session CSV, ARS408 object list (header fix), TU Delft example, rig.yaml / session folder."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.extrinsics.radar import quantisation_report
from radarcal.io.radar import read_ars408_csv, read_radar_csv, read_radar_session, read_rig_yaml, read_tudelft_accumulator, read_tudelft_example


def test_session_csv_header_comments_optional_columns(tmp_path):
    p = tmp_path / "radar.csv"
    p.write_text("radar,x,y,rcs,velocity\n# a comment\nradar_left,1.5,-0.25,12.5,0.1\nradar_middle,2,0.5\n\nradar_right,3.25,1.0,7,\n")
    d = read_radar_csv(p)
    assert d.radar.tolist() == ["radar_left", "radar_middle", "radar_right"]
    np.testing.assert_allclose(d.xy, [[1.5, -0.25], [2.0, 0.5], [3.25, 1.0]])
    np.testing.assert_allclose(d.rcs, [12.5, np.nan, 7.0])
    assert np.isnan(d.velocity[1]) and d.velocity[0] == 0.1
    np.testing.assert_allclose(d.of("radar_middle"), [[2.0, 0.5]])


@pytest.mark.parametrize("body, msg", [("radar_left,1.0,abc\n", "line 2: y 'abc' is not a number"), ("radar_left,1.0\n", "line 2: expected radar,x,y"),
                                       ("radar_left,1,2,3,4,5\n", "line 2: expected"), (",1,2\n", "line 2: empty radar name"), ("radar_left,nan,1\n", "line 2: x is not finite")])
def test_session_csv_errors_name_file_and_line(tmp_path, body, msg):
    p = tmp_path / "radar.csv"
    p.write_text("radar,x,y\n" + body)
    with pytest.raises(InputError) as e:
        read_radar_csv(p)
    assert str(p) in str(e.value) and msg in str(e.value)


def test_ars408_real_file_header_fix(shared):
    root = shared("opencalib_radar2lidar")
    o = read_ars408_csv(root / "radar2lidar" / "front_radar.csv")
    # SOURCE.md: 575 rows, 7 scans of 81-83 objects, 26 columns (header has 25 names: fused prob_of_existobject_type)
    assert len(o.xy) == 575
    assert "prob_of_existobject_type" in o.header_fixed
    assert "prob_of_exist" in o.columns and "object_type" in o.columns and len(o.columns) == 26
    assert len(np.unique(o.scan)) == 7
    sizes = np.bincount(o.scan)
    assert sizes.min() >= 81 and sizes.max() <= 83
    assert o.xy[:, 0].min() == pytest.approx(4.8, abs=1e-4) and o.xy[:, 0].max() == pytest.approx(247.4, abs=1e-4)
    assert o.xy[:, 1].min() == pytest.approx(-58.0, abs=1e-4) and o.xy[:, 1].max() == pytest.approx(38.0, abs=1e-4)
    assert o.rcs.min() == pytest.approx(-6.0) and o.rcs.max() == pytest.approx(33.0)
    q = quantisation_report(o.xy)  # SOURCE.md: positions quantised to 0.2 m
    assert q["quantised"] and q["step_m"] == 0.2 and not q["averaging_removes_it"]
    assert q["sigma_per_axis_m"] == pytest.approx(0.2 / np.sqrt(12))


def test_ars408_bad_row(tmp_path):
    p = tmp_path / "front_radar.csv"
    p.write_text("time_ns,track_id,position_x,position_y\n1,0,1.0,2.0\n2,1,x,2.0\n")
    with pytest.raises(InputError, match="line 3: position_x 'x' is not a number"):
        read_ars408_csv(p)


def test_tudelft_readers(shared):
    root = shared("tudelft_msc_example")
    circles, radar = read_tudelft_example(root / "optimization_example_data")
    assert circles.shape == (29, 4, 3) and radar.shape == (29, 2)
    r = np.linalg.norm(radar, axis=1)  # SOURCE.md: ranges 1.26-3.31 m
    assert r.min() == pytest.approx(1.26, abs=0.01) and r.max() == pytest.approx(3.31, abs=0.01)
    assert np.all(np.abs(circles[:, :, 2] + 0.9) < 0.2)  # reflector centres at z ~ -0.90 m
    c12, r12, rcs = read_tudelft_accumulator(root / "accumulator" / "example_data.yaml")
    assert c12.shape == (12, 4, 3) and r12.shape == (12, 2)
    assert rcs.min() == pytest.approx(2.9, abs=0.05) and rcs.max() == pytest.approx(9.9, abs=0.05)


def test_rig_yaml_errors(tmp_path):
    p = tmp_path / "rig.yaml"
    p.write_text("main_lidar: l0\nradars:\n  r0: {mount_height_m: high}\n")
    with pytest.raises(InputError, match="radars.r0.mount_height_m"):
        read_rig_yaml(p)
    p.write_text("main_lidar: l0\nradars: {r0: {initial_T_main: [1, 2, 3]}}\n")
    with pytest.raises(InputError, match="r0.initial_T_main"):
        read_rig_yaml(p)
    p.write_text("main_lidar: l0\nradars: {r0: {}}\nreference_radar: r9\n")
    with pytest.raises(InputError, match="reference_radar 'r9'"):
        read_rig_yaml(p)
    p.write_text("main_lidar: l0\nradars: {r0: {mount_height_m: 0.5, initial_T_main: [1, 0, 0, 0, 0, 90]}}\n")
    rig = read_rig_yaml(p)
    assert rig.reference_radar == "r0" and rig.mount_heights == {"r0": 0.5}
    np.testing.assert_allclose(rig.init_T_main["r0"][:2, :2], [[0, -1], [1, 0]], atol=1e-12)


def test_session_unknown_radar_and_ars408_scene(tmp_path):
    from radarcal.io.clouds import write_pcd

    (tmp_path / "scenes" / "a").mkdir(parents=True)
    (tmp_path / "rig.yaml").write_text("main_lidar: l0\nradars: {front: {mount_height_m: 0.5}}\n")
    write_pcd(tmp_path / "scenes" / "a" / "l0.pcd", np.zeros((5, 3)))
    (tmp_path / "scenes" / "a" / "radar.csv").write_text("rear,1,2\n")
    with pytest.raises(InputError, match="rear not in rig.yaml"):
        read_radar_session(tmp_path)
    (tmp_path / "scenes" / "a" / "radar.csv").unlink()
    (tmp_path / "scenes" / "a" / "front.csv").write_text(
        "time_ns,track_id,velocity_x,velocity_y,position_x,position_y,dynprop,rcs,prob_of_existobject_type,invalid_state\n1,0,0,0,2.2,0.4,1,9.0,3,0,0\n")
    s = read_radar_session(tmp_path)
    np.testing.assert_allclose(s.scenes[0].detections.of("front"), [[2.2, 0.4]])
    assert "missing comma" in s.scenes[0].notes[0]

"""``radarcal run`` with several cameras (issue #19) on a generated wide + tele replay, scored against its truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal.cli.main import main
from radarcal.field import load_field
from radarcal.io.replay import open_replay_folder
from radarcal.runtime.evaluation import band_scores
from radarcal.synth.field import FieldSceneConfig
from radarcal.synth.field_cameras import MultiCameraConfig, parse_camera_specs, write_multicam_replay

GAP = (1.2, 1.5)  # cam1 unplugged 1.2 .. 2.7 s of a 3 s replay


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    out = tmp_path_factory.mktemp("multicam") / "rep"
    cfg = FieldSceneConfig(frames=90, seed=4, robots=5, image_scale=0.1, image_every=90, lidar_points=5000)
    write_multicam_replay(out, load_field("rmuc2024"), MultiCameraConfig(cfg, parse_camera_specs("cam0=6mm,cam1=16mm"), gaps={"cam1": GAP}))
    return out


def _run(replay, tmp_path, capsys, *extra):
    out = tmp_path / "o.jsonl"
    code = main(["run", "--replay", str(replay), "--out", str(out), "--json", *extra])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    return json.loads(cap.out), [json.loads(x) for x in out.read_text().splitlines()], cap.err


def test_two_cameras_one_entry_per_robot_and_an_unplugged_camera(replay, tmp_path, capsys):
    s, lines, _ = _run(replay, tmp_path, capsys)
    assert s["cameras"] == ["cam0", "cam1"] and s["frames"] == 90 and s["camera_missing_frames"]["cam1"] >= 25
    truth = open_replay_folder(replay).truth_by_frame()
    origin = np.asarray(json.loads((replay / "truth.json").read_text())["cameras"]["cam0"]["T_field_cam"])[:2, 3]
    acc = band_scores(lines, truth, origin, 0.0)
    assert acc["median_m"] < 0.15 and acc["located"] >= 0.8 * acc["robot_frames"], acc
    for ln in lines:
        labels = [r["label"] for r in ln["robots"] if r["label"]]
        assert len(labels) == len(set(labels))
        t = ln["t"]
        if GAP[0] + 0.6 < t < GAP[0] + GAP[1]:  # unplugged: cam0 alone, cam1 named missing
            assert ln["cameras"].keys() == {"cam0"} and ln["missing_cameras"] == ["cam1"]
        elif t < GAP[0] or t > GAP[0] + GAP[1] + 0.05:
            assert ln["cameras"].keys() == {"cam0", "cam1"} and ln["missing_cameras"] == []
    during = [ln for ln in lines if GAP[0] + 0.6 < ln["t"] < GAP[0] + GAP[1]]
    gap = band_scores(during, truth, origin, 0.0, seen_by="cam0")  # the wide camera keeps localising alone
    assert gap["frames"] >= 20 and gap["median_m"] < 0.2 and gap["located"] >= 0.8 * gap["robot_frames"], gap


@pytest.mark.slow
def test_status_line_names_the_missing_camera(replay, tmp_path, capsys):
    code = main(["run", "--replay", str(replay), "--max-frames", "60"])
    cap = capsys.readouterr()
    assert code == 0 and "cam1 MISSING" in cap.err and "camera cam0, cam1 (missing" in cap.out


@pytest.mark.slow
def test_one_camera_of_a_multi_camera_replay(replay, tmp_path, capsys):
    s, lines, _ = _run(replay, tmp_path, capsys, "--camera", "cam0")
    assert s["cameras"] == ["cam0"] and all(ln["cameras"].keys() == {"cam0"} for ln in lines)


@pytest.mark.parametrize("args, where", [(["--camera", "cam9"], "no camera 'cam9'"), (["--ui", "0"], "--ui"), (["--detections", "x.jsonl"], "--detections")])
def test_multi_camera_bad_options(replay, capsys, args, where):
    assert main(["run", "--replay", str(replay), *args]) == 2
    assert where in capsys.readouterr().err


def test_several_videos_need_names(replay, capsys):
    cams = replay / "cameras"
    assert main(["run", "--bundle", str(replay / "calib.yaml"), "--video", f"cam0={cams / 'cam0' / 'images'}", "--video", str(cams / "cam1" / "images")]) == 2
    assert "NAME=SRC" in capsys.readouterr().err


@pytest.mark.slow
def test_a_hidden_robot_s_tele_box_does_not_move_its_track_onto_the_robot_in_front(tmp_path, capsys):
    """Benchmark family A seed 5 (`benchmarks.multicam A:5`, wide 6 mm + tele 16 mm, 10 s): before, the tele's boxes of
    blue_2 hidden behind blue_1 / red_1 took red_1's depth, then the ground ray from blue_1's outline, and moved
    blue_2's LiDAR-lost track 4.4 m onto red_1 (blue_4's 9.5 m onto blue_7): wide + tele p95 beyond 15 m 1.74 m, the
    wide camera alone 0.39 m. Now 0.49 m (all entries; 0.43 m before the bottom-edge test of on_other_robot, a
    start-up mislabel lasting longer) and 0.19 m (sent on the referee map)."""
    rep = tmp_path / "a5"
    cfg = FieldSceneConfig(frames=300, seed=5, robots=8, image_scale=0.1, image_every=300, station="red")
    write_multicam_replay(rep, load_field("rmuc2024"), MultiCameraConfig(cfg, parse_camera_specs("cam0=6mm,cam1=16mm")))
    truth = open_replay_folder(rep).truth_by_frame()
    origin = np.asarray(json.loads((rep / "truth.json").read_text())["cameras"]["cam0"]["T_field_cam"])[:2, 3]
    _, lines, _ = _run(rep, tmp_path, capsys, "--camera", "cam0,cam1")
    b = band_scores(lines, truth, origin, 15.0, seen_by="cam0")
    assert b["p95_m"] < 0.6 and b["p95_sent_m"] < 0.3 and b["correct_label_pct"] > 85.0 and b["twice_labelled_pct"] < 1.0, b
    far = [ln for ln in lines if 7.9 < ln["t"] < 9.0]  # blue_2 behind blue_1 and red_1
    for ln in far:
        own = np.asarray(next(r for r in truth[ln["frame"]]["robots"] if r["label"] == "blue_2")["p_field"][:2])
        for e in ln["robots"]:
            if e["label"] == "blue_2":
                assert np.hypot(e["x"] - own[0], e["y"] - own[1]) < 1.0, (ln["t"], e)

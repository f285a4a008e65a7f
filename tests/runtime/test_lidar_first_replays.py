"""LiDAR-first vs box path on `radarcal synth match` replays (visible-part boxes, misses, false positives, swaps,
late clouds, calibration error). Slow: each replay takes ~30-60 s to generate (`make test-slow`). The thresholds
are the figures measured in docs/runtime.md with a margin, not the issue's goals (not all reached, see there)."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from radarcal.cli.main import main

pytestmark = pytest.mark.slow


def _synth(tmp_path, name, *extra):
    out = tmp_path / name
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["synth", "match", str(out), "--frames", "300", *extra, "--json"]) == 0
    return out


def _run(rep, capsys, *extra):
    capsys.readouterr()
    out = rep / f"out{'_'.join(extra)}.jsonl"
    assert main(["run", "--replay", str(rep), "--out", str(out), "-q", "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)["accuracy"], [json.loads(x) for x in out.read_text().splitlines()]


def test_occlusion_replay_hidden_robot_keeps_track_and_label(tmp_path, capsys):
    rep = _synth(tmp_path, "occ", "--seed", "4", "--scenario", "occlusion")
    acc, lines = _run(rep, capsys)
    truth = {json.loads(x)["frame"]: json.loads(x) for x in (rep / "truth.jsonl").read_text().splitlines()}
    dets = {json.loads(x)["frame"]: json.loads(x) for x in (rep / "detections.jsonl").read_text().splitlines()}
    n = kept = 0
    for o in lines:
        boxed = {b["label"] for b in dets[o["frame"]]["boxes"]}
        out = {r["label"]: r for r in o["robots"] if r["label"]}
        for r in truth[o["frame"]]["robots"]:
            if o["t"] >= 1.0 and r["label"] not in boxed and r["lidar_hits"] >= 3:  # no box, the LiDAR sees it
                n += 1
                e = out.get(r["label"])
                kept += e is not None and np.hypot(e["x"] - r["p_field"][0], e["y"] - r["p_field"][1]) < 0.6
    print(f"occlusion: {kept}/{n} hidden-from-camera robot-frames kept with their label; {acc}")
    assert n >= 20 and kept >= 0.9 * n
    assert acc["right_within_0.6m_pct"] > 85 and acc["false_per_frame"] < 0.2


def test_realistic_replay_auto_box_and_lidar_only(tmp_path, capsys):
    rep = _synth(tmp_path, "r7", "--seed", "7")
    auto, _ = _run(rep, capsys)
    box, _ = _run(rep, capsys, "--localise", "box")
    lidar, _ = _run(rep, capsys, "--no-camera")
    print(f"auto {auto}\nbox {box}\nlidar only {lidar}")
    # seed 7, never tuned on, is the hardest measured (docs/runtime.md: auto 78.9 -> 82.8 -> 80.6 % since the pile-up
    # rule of the sparse components, 81.5 % before a label boxed on another track decayed on the stale one, 84.6 %
    # after; box 85.7 % right)
    assert auto["right_within_0.6m_pct"] > 83.5 and auto["median_m"] < 0.2 and auto["wrong_label_pct"] < 6
    assert auto["false_per_frame"] < 0.35 and auto["longest_ghost_s"] < 1.0
    assert box["right_within_0.6m_pct"] > 75
    assert lidar["longest_ghost_s"] < 1.0 and lidar["false_per_frame"] < 0.4  # people at the boundary never become robots
    # seed 7: 51.2 % before the sparse components / static-suspect changes, 66.1 % after, 79.8 % with the LiDAR-only
    # 1.5 m/s^2, the aerial sigma and sparse births, 83.3 % with the LiDAR-only IMM, the cell-grid wall margins and the
    # residual ground tolerance (89-94 % on the other seeds; goal 95 %: not met, docs/runtime.md)
    assert lidar["lidar_within_0.3m_pct"] > 81


def test_one_robot_is_never_on_the_referee_map_twice(tmp_path, capsys):
    """Issue #19: a crowded blue-station wide + tele replay (10 robots; before the one-entry-per-robot rule 13 % of
    its frames had one robot twice among the labelled measured entries, with one camera or two)."""
    from radarcal.field import load_field
    from radarcal.io.replay import open_replay_folder
    from radarcal.runtime.evaluation import band_scores
    from radarcal.synth.field import FieldSceneConfig
    from radarcal.synth.field_cameras import MultiCameraConfig, parse_camera_specs, write_multicam_replay

    rep = tmp_path / "crowd"
    cfg = FieldSceneConfig(frames=120, seed=11, robots=10, image_scale=0.1, image_every=120, lidar_points=5000, station="blue")
    write_multicam_replay(rep, load_field("rmuc2024"), MultiCameraConfig(cfg, parse_camera_specs("cam0=6mm,cam1=12mm@19:9")))
    truth = open_replay_folder(rep).truth_by_frame()
    origin = np.asarray(json.loads((rep / "truth.json").read_text())["cameras"]["cam0"]["T_field_cam"])[:2, 3]
    for cams in ("cam0", "cam0,cam1"):
        _, lines = _run(rep, capsys, "--camera", cams)
        b = band_scores(lines, truth, origin, 0.0, seen_by="cam0")
        assert b["twice_labelled_pct"] < 1.0 and b["correct_label_pct"] > 80.0 and b["median_m"] < 0.12, (cams, b)

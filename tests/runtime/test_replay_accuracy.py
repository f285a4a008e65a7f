"""Done-when figures on freshly generated 300-frame field replays (robots moving, LiDAR 10 Hz, exact boxes).
Slow: each replay takes ~20-30 s to generate on a busy machine (`make test-slow`).

``--localise box`` reports every visible robot from its first box. The default ``auto`` holds a new track back until
it is confirmed (3 consistent box fixes or 2 cluster hits, docs/runtime.md "Tracks"): a robot is missing for its
first ~0.1 s in view, so its bounds are on the right-label rate and on the misses after the first 0.3 s. Measured
(2026-12-02, main a895496): seed 11 auto 96.7 % right within 0.6 m, 5 of 1631 missed after 0.3 s (box 98.3 %, 0
missed); seed 12 auto 92.6 %, 22 of 1701 missed, p95 0.64 m (box 95.5 %, p95 0.42 m); LiDAR cut 97.0 %, 1 of 1723 missed.
The sparse components (c4892c5) took seed 12 to 89.6 %, 66 of 1701 missed (fails here); since the camera-fixed tracks
take none (``Tracker3D.update_sparse``) 92.4 %, 22 of 1701, p95 0.68 m. The multi-camera rule
``lidar_first.on_other_robot`` took it to 52 of 1701 missed (red_3's fixes beside blue_7 dropped); since a fix with no
LiDAR-measured track of its label elsewhere is dropped only when its box stands behind it (``pipeline.foot_beyond``) 93.8 %,
22 of 1701, p95 0.43 m. The bounds hold today's level; issue #15's >= 95 % is not met by auto on seed 12
(docs/runtime.md)."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from radarcal.cli.main import main

pytestmark = pytest.mark.slow


def _synth(tmp_path, name, *extra):
    out = tmp_path / name
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["synth", "field", str(out), "--frames", "300", *extra, "--json"]) == 0
    return out


def _run(replay, capsys, tmp_path, localise="auto"):
    capsys.readouterr()
    out = tmp_path / f"{replay.name}_{localise}.jsonl"
    assert main(["run", "--replay", str(replay), "--out", str(out), "--localise", localise, "--json"]) == 0
    return json.loads(capsys.readouterr().out), [json.loads(x) for x in out.read_text().splitlines()]


def _truth(replay) -> dict:
    return {json.loads(x)["frame"]: json.loads(x) for x in (replay / "truth.jsonl").read_text().splitlines()}


def _missing_after(replay, lines, t0: float) -> tuple[int, int]:
    """(visible robot-frames at t >= t0 whose label no output entry has, visible robot-frames at t >= t0)."""
    truth = _truth(replay)
    missing = visible = 0
    for ln in lines:
        if ln["t"] < t0:
            continue
        labels = {r["label"] for r in ln["robots"]}
        vis = [r["label"] for r in truth[ln["frame"]]["robots"] if r["visible"]]
        visible += len(vis)
        missing += sum(lb not in labels for lb in vis)
    return missing, visible


def _assert_default_accuracy(replay, lines, acc):
    missing, visible = _missing_after(replay, lines, 0.3)
    assert missing <= 0.02 * visible, (missing, visible)
    assert acc["right_within_0.6m_pct"] >= 90.0 and acc["wrong_label_pct"] < 2.0
    assert acc["median_m"] < 0.3 and acc["p95_m"] < 0.8


@pytest.mark.parametrize("seed", [11, 12])
def test_generated_replay_accuracy(tmp_path, capsys, seed):
    replay = _synth(tmp_path, f"r{seed}", "--seed", str(seed))
    s, lines = _run(replay, capsys, tmp_path)
    print(f"seed {seed} auto: {s['accuracy']}")
    _assert_default_accuracy(replay, lines, s["accuracy"])
    box, _ = _run(replay, capsys, tmp_path, "box")
    acc = box["accuracy"]
    print(f"seed {seed} box: {acc}")
    assert acc["missing"] == 0
    assert acc["median_m"] < 0.3 and acc["p95_m"] < 0.8


def test_generated_replay_lidar_cut_2s(tmp_path, capsys):
    rep = _synth(tmp_path, "gap", "--seed", "13", "--lidar-gap", "4:2")
    s, lines = _run(rep, capsys, tmp_path)
    truth = _truth(rep)
    n_gap = 0
    for ln in lines:
        if 4.0 <= ln["t"] < 6.0:
            vis = {r["label"] for r in truth[ln["frame"]]["robots"] if r["visible"]}
            assert vis <= {r["label"] for r in ln["robots"]}, ln["t"]
            n_gap += 1
        if 5.1 <= ln["t"] < 6.0:  # the depth window (0.5 s) has emptied: ground-ray fixes only
            assert all(r["source"] in ("ground", "predicted") for r in ln["robots"])
    assert n_gap >= 59
    print(f"LiDAR cut 4..6 s: {s['accuracy']}")
    _assert_default_accuracy(rep, lines, s["accuracy"])

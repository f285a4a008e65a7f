"""``synth match`` windows: --camera-miss drops only the boxes (the LiDAR still sees the robot), --lidar-miss only the
robot's LiDAR returns (the camera still sees it), --absent takes the robot off the field (no returns, no box, not in
the truth); the other robots are unchanged."""

from __future__ import annotations

import json

import pytest

from radarcal.errors import InputError
from radarcal.cli.synth_match_cmd import parse_robot_windows
from radarcal.field import load_field
from radarcal.synth.detections import MatchConfig, write_match_replay


def _lines(path):
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


@pytest.fixture(scope="module")
def replays(tmp_path_factory):
    fm = load_field("rmuc2024")
    base = dict(frames=60, seed=3, robots=3, aerial=False, people=0, lidar_points=3000, false_positives=0.0, miss=0.0, swap=0.0)
    out = {}
    for name, extra in (("base", {}), ("miss", {"camera_miss": (("blue_3", 0.5, 1.2),)}), ("absent", {"absent": (("blue_1", 0.0, 0.8),)}),
                        ("lidar_miss", {"lidar_miss": (("blue_3", 0.5, 1.2),)})):
        d = tmp_path_factory.mktemp(name)
        write_match_replay(d, fm, MatchConfig(**base, **extra))
        out[name] = (_lines(d / "truth.jsonl"), _lines(d / "detections.jsonl"))
    return out


@pytest.mark.slow
def test_absent_window(replays):
    (t0, _), (t1, d1) = replays["base"], replays["absent"]
    for a, b, db in zip(t0, t1, d1):
        labels_b = {r["label"]: r for r in b["robots"]}
        if b["t"] <= 0.8:
            assert "blue_1" not in labels_b and "blue_1" not in {x["label"] for x in db["boxes"]}  # off the field: not in truth, no box
        else:
            assert "blue_1" in labels_b
        pa = {r["label"]: r["p_field"] for r in a["robots"]}
        assert all(labels_b[lb]["p_field"] == pa[lb] for lb in ("blue_3", "blue_7"))  # the others move as without the window
    assert any(r["label"] == "blue_1" and r["lidar_hits"] > 0 for x in t1 if x["t"] > 1.0 for r in x["robots"])  # back on the field


@pytest.mark.slow
def test_camera_miss_window(replays):
    (t0, d0), (t1, d1) = replays["base"], replays["miss"]
    miss_seen = 0
    for a, b, da, db in zip(t0, t1, d0, d1):
        t = b["t"]
        labels_b = {r["label"]: r for r in b["robots"]}
        boxes_b = {x["label"] for x in db["boxes"]}
        if 0.5 <= t <= 1.2:
            assert "blue_3" not in boxes_b and labels_b["blue_3"].get("camera_miss") is True
            hits = labels_b["blue_3"]["lidar_hits"]
            assert hits == next(r for r in a["robots"] if r["label"] == "blue_3")["lidar_hits"]  # the LiDAR sees it as in the base replay
            miss_seen += hits
        else:
            assert "camera_miss" not in labels_b["blue_3"]
        # blue_3 / blue_7 truth positions are unchanged by the windows
        pa = {r["label"]: r["p_field"] for r in a["robots"]}
        for lb in ("blue_3", "blue_7"):
            assert labels_b[lb]["p_field"] == pa[lb]
    assert miss_seen >= 10  # returns on it in the window
    # every other box is the base replay's (same noise); blue_3's too outside the window
    for a, b in zip(d0, d1):
        keep = [x for x in a["boxes"] if not (x["label"] == "blue_3" and 0.5 <= a["t"] <= 1.2)]
        assert b["boxes"] == keep


@pytest.mark.slow
def test_lidar_miss_window(replays):
    """No return from blue_3 inside the window (every cloud that ends in it), the base replay's returns outside it;
    its boxes and every other robot as in the base replay."""
    (t0, d0), (t1, d1) = replays["base"], replays["lidar_miss"]
    inside = outside = 0
    for a, b, da, db in zip(t0, t1, d0, d1):
        ra = {r["label"]: r for r in a["robots"]}
        rb = {r["label"]: r for r in b["robots"]}
        assert db["boxes"] == da["boxes"]  # the camera sees what it saw
        if 0.6 <= b["t"] <= 1.2:  # the last cloud before the frame ended inside the window
            assert rb["blue_3"]["lidar_hits"] == 0 and rb["blue_3"].get("lidar_miss") is True
            inside += ra["blue_3"]["lidar_hits"]
        elif b["t"] < 0.5 or b["t"] > 1.4:
            assert rb["blue_3"]["lidar_hits"] == ra["blue_3"]["lidar_hits"] and "lidar_miss" not in rb["blue_3"]
            outside += rb["blue_3"]["lidar_hits"]
        for lb in ("blue_1", "blue_7"):
            assert rb[lb]["lidar_hits"] == ra[lb]["lidar_hits"] and rb[lb]["p_field"] == ra[lb]["p_field"]
    assert inside >= 10 and outside >= 10  # the base replay had returns there: the window removed them


def test_window_option_parsing():
    assert parse_robot_windows(["blue_3:2:12"], "--camera-miss", True) == (("blue_3", 2.0, 12.0),)
    assert parse_robot_windows(["red_4"], "--absent", False)[0][2] == float("inf")
    for bad in ("blue_3", "green_1:0:1", "blue_3:5:2", "blue_9:0:1", "blue_3:a:b"):
        with pytest.raises(InputError):
            parse_robot_windows([bad], "--camera-miss", True)

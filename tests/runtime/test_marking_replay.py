"""Guessing on a generated match against the generator's truth (issue #20): the camera misses one robot for 10 s and
the LiDAR loses it for the first 3 s of that (longer than the tracker coasts), so the LiDAR re-finds it as an unnamed
track while no box can name it. Guessing must raise that robot's correct-mark seconds (the referee simulator scores
them against truth.jsonl); the same robot truly absent must cost less than 1/3 of its absence in wrong marks."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow

SEED, ROBOT, FRAMES = 2, "blue_2", 900  # 30 s: the first 30 s of benchmarks.marking_offline's seed-2 replays
GAIN_S = 3.0  # seed 2, 45 s: 35.8 -> 42.0 correct s (the guess holds the re-found track 19-25 s)
# wrong-mark seconds the guess may add: 8d1d190 3.4 vs 2.8 s without; with the range-grown surface tolerance (round 7)
# 3.1 vs 2.0 s - both fewer, the run without the guess gaining more (was 1.0 s)
EXTRA_WRONG_S = 1.5


@pytest.fixture(scope="module")
def replays(tmp_path_factory):
    from benchmarks.marking_offline import DROPOUT_S
    from benchmarks.referee import MISS, _make

    d = tmp_path_factory.mktemp("marking_replay")
    hard = _make(d / "hard", SEED, FRAMES, ["--camera-miss", f"{ROBOT}:{MISS[0]:g}:{MISS[1]:g}", "--lidar-miss", f"{ROBOT}:{MISS[0]:g}:{MISS[0] + DROPOUT_S:g}"])
    absent = _make(d / "absent", SEED, FRAMES, ["--absent", ROBOT])
    return hard, absent


def test_guess_raises_correct_marks_of_a_robot_lost_by_both_sensors(replays):
    from benchmarks.marking_offline import play
    from benchmarks.referee import _row

    hard, _ = replays
    on = _row(play(hard, 2026, {"guess": True})[0], ROBOT)
    off = _row(play(hard, 2026, {"guess": False})[0], ROBOT)
    print("correct s with guess", on["correct_s"], "without", off["correct_s"], "wrong", on["wrong_s"], off["wrong_s"])
    assert on["correct_s"] >= off["correct_s"] + GAIN_S
    assert on["wrong_s"] <= off["wrong_s"] + EXTRA_WRONG_S


def test_guess_of_the_truly_absent_robot_costs_under_a_third(replays):
    from benchmarks.marking_offline import play
    from benchmarks.referee import _row

    _, absent = replays
    s, _ = play(absent, 2026, {"guess": True})
    r = _row(s, ROBOT)
    print("absent: wrong s with guess", r["wrong_s"], "of", s["match_s"])
    assert r["wrong_s"] < s["match_s"] / 3

"""Fixtures of the synth tests: the referee simulator played against ``radarcal run --serial`` over a pty."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def referee_match(tmp_path):
    """``play(replay, season, *run_args, team="red", **sim_kw) -> (sim summary, run summary, log path)``: a
    :class:`~radarcal.synth.referee_sim.RefereeSim` on a new pty, ``radarcal run --replay REPLAY --serial PTY
    --speed 1 --json`` against it (this worktree's package), every frame logged to a JSON-lines file."""
    from radarcal.io.replay import open_replay_folder
    from radarcal.runtime.referee_season import rules
    from radarcal.synth.referee_serve import play_match
    from radarcal.synth.referee_sim import RefereeSim, Truth

    def play(replay, season: int, *run_args: str, team: str = "red", **sim_kw):
        rep = open_replay_folder(replay)
        sim = RefereeSim(rules(season), Truth.from_lines(rep.truth_by_frame().values()), team=team, **sim_kw)
        log = tmp_path / f"referee_{season}.jsonl"
        env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
        cmd = [sys.executable, "-m", "radarcal", "run", "--replay", str(replay), "--season", str(season), "--speed", "1", "--quiet", "--json", *run_args]
        res, proc = play_match(sim, cmd, log_path=log, timeout_s=300, env=env, cwd=REPO)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return res.summary, json.loads(proc.stdout), log

    return play

"""End to end: ``radarcal run --serial PTY`` against the referee simulator on the sample replay (real time)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from radarcal.runtime import referee as rp

SAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "sample_replay"


@pytest.mark.slow
@pytest.mark.parametrize("season", [2026, 2023])
def test_run_against_the_simulator_over_a_pty(referee_match, season):
    sim, run, log = referee_match(SAMPLE, season, "--max-frames", "150")
    link = sim["link"]
    # every frame decoded by the simulator's own decoder: CRCs, the season's layout, no budget or rate breach
    assert link["frames"] >= 15 and link["layout_checked"] == link["by_cmd"]["0x0305"]
    assert link["malformed_total"] == 0 and link["over_rate"] == link["over_link_budget"] == link["over_interaction_budget"] == 0
    assert run["serial"]["team"] == "red" and run["serial"]["received"] > 10  # radarcal parsed the simulator's 0x0201 / 0x0001
    # the sample's enemy robots are in view: each is correctly marked most of the 5 s radarcal ran
    rows = {r["robot"]: r for r in sim["robots"] if r["off_field_s"] < sim["match_s"]}
    assert len(rows) >= 3
    for r in rows.values():
        assert r["correct_s"] >= 0.6 * 5.0, r
    # the log holds both directions, each frame re-parseable with the package codec
    lines = [json.loads(x) for x in log.read_text().splitlines()]
    rx = [x for x in lines if x.get("dir") == "rx" and "hex" in x]
    tx = [x for x in lines if x.get("dir") == "tx"]
    assert len(rx) == link["frames"] and len(tx) > 10 and "summary" in lines[-1]
    for x in rx[:5] + tx[:5]:
        rp.parse_frame(bytes.fromhex(x["hex"]))

"""The per-season referee table: every season present, layouts consistent with the encoder, uncertain items marked."""

from __future__ import annotations

import pytest

from radarcal.runtime import referee as rp
from radarcal.runtime import referee_season as rs
from radarcal.runtime.serial_link import referee_limits


def test_every_known_season_has_rules_and_the_encoder_agrees_on_sizes():
    assert rs.KNOWN_SEASONS == (2021, 2022, 2023, 2024, 2025, 2026) == rp.KNOWN_SEASONS
    for season in rs.KNOWN_SEASONS:
        r = rs.rules(season)
        assert rp.map_layout(season) == r.map_layout.value
        payload = rp.map_payload(season, {1: (10.0, 7.5)}, {1: (3.0, 4.0)})[0]
        assert len(payload) == r.map_bytes  # the table's size is the encoder's size
        assert referee_limits(season)[rp.CMD_MAP] == r.map_hz.value
        assert r.link_bytes_per_s.value <= rs.LINE_BYTES_PER_S


def test_documented_facts_and_uncertainty_flags():
    r26, r24, r23 = rs.rules(2026), rs.rules(2024), rs.rules(2023)
    assert (r26.map_layout.value, r26.map_hz.value, r26.interaction_hz.value) == ("all48", 5.0, 30.0)
    assert (r26.mark_rule.value, r26.vulnerable_at.value, r26.radar_cmd_bytes.value) == ("progress_bits", 100, 8)
    assert not r26.vulnerable_at.uncertain and r26.score_correct_per_s.uncertain and r26.score_wrong_per_s.uncertain
    assert (r26.score_correct_per_s.value, r26.score_wrong_per_s.value) == (5.0, -10.0)
    assert r23.mark_rule.value == "distance" and r23.mark_radius_m.value == 0.6 and not r23.mark_radius_m.uncertain
    assert r24.mark_feedback_bytes.value == 6 and r24.progress_max.uncertain
    assert r26.map_slots == ((1, 2, 3, 4, 6, 7), (1, 2, 3, 4, 6, 7)) and r23.single_target
    with pytest.raises(KeyError, match="2021..2026"):
        rs.rules(2019)


def test_replace_overrides_a_value_and_table_rows_mark_uncertain():
    r = rs.rules(2026).replace(score_wrong_per_s=-5.0)
    assert r.score_wrong_per_s.value == -5.0 and rs.rules(2026).score_wrong_per_s.value == -10.0
    rows = rs.season_table_rows()
    assert rows[0][1:] == [str(s) for s in rs.KNOWN_SEASONS]
    score = next(row for row in rows if row[0].startswith("score wrong"))
    assert all(c.endswith("?") for c in score[1:])

"""The referee simulator's rules against scripted marks with known truth (no radarcal run involved)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from radarcal.runtime import referee as rp
from radarcal.runtime.referee_season import KNOWN_SEASONS, rules
from radarcal.synth.referee_sim import RefereeSim, Truth, decode_map

# the 2024-layout example frame of shared/referee_protocol.md §6 (CRCs from an independent script): hero (10, 7.5), sentry (20, 5)
MAP_2024 = "A5 18 00 00 AC 05 03 E8 03 EE 02 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 D0 07 F4 01 BC AF"
MAP_SINGLE_2023 = "A5 0A 00 03 4B 05 03 65 00 00 00 20 41 00 00 F0 40 F0 D8"  # blue hero at (10, 7.5), floats


def static_truth(positions: dict[str, tuple[float, float]], duration: float = 40.0, fps: float = 30.0, absent: dict | None = None) -> Truth:
    lines = []
    for k in range(int(duration * fps) + 1):
        t = k / fps
        robots = [{"label": lb, "p_field": [x, y, 0.0]} for lb, (x, y) in positions.items() if not (absent and lb in absent and absent[lb][0] <= t <= absent[lb][1])]
        lines.append({"t": t, "robots": robots})
    return Truth.from_lines(lines)


def play(sim: RefereeSim, frames_at, until: float, hz: float = 5.0):
    """Send ``frames_at(t) -> [(cmd, data)]`` every 1/hz s and advance the clock to ``until``."""
    n = int(round(until * hz))
    for k in range(n + 1):
        t = k / hz
        sim.advance(t)
        for cmd, data in frames_at(t):
            sim.receive(t, rp.Frame(cmd, data))
    sim.advance(until)


def single10(x: float, y: float, rid: int = 101) -> tuple[int, bytes]:
    return rp.CMD_MAP, struct.pack("<Hff", rid, x, y)


def test_2023_distance_rule_half_a_metre_counts_and_point_seven_does_not():
    truth = static_truth({"blue_1": (10.0, 7.0)}, duration=20.0)
    ok = RefereeSim(rules(2023), truth)
    play(ok, lambda t: [single10(10.3, 7.4)], 10.0)  # 0.5 m off
    far = RefereeSim(rules(2023), truth)
    play(far, lambda t: [single10(10.0, 7.7)], 10.0)  # 0.7 m off
    a, b = ok.robots["blue_1"], far.robots["blue_1"]
    assert a.correct_s == pytest.approx(10.0, abs=0.11) and a.wrong_s == 0
    assert b.correct_s == 0 and b.wrong_s == pytest.approx(10.0, abs=0.11)
    assert ok.summary()["robots"][0]["vulnerable_frac"] is None  # no progress rule in 2023
    assert ok.malformed == 0 and ok.layout_checked == 51


def test_2026_progress_reaches_100_after_20_s_of_correct_marks_and_drains_when_unsent():
    r = rules(2026)
    truth = static_truth({"blue_1": (10.0, 7.0), "blue_3": (20.0, 4.0)}, duration=60.0)
    sim = RefereeSim(r, truth)
    mark = rp.map_payload(2026, {1: (10.05, 6.98)}, {}, "blue")[0]  # hero marked, infantry 3 never
    bits_at = {}

    def frames(t):
        if t <= 40.0:
            return [(rp.CMD_MAP, mark)]
        return []

    for k in range(0, 5 * 60 + 1):
        t = k / 5
        sim.advance(t)
        for cmd, data in frames(t):
            sim.receive(t, rp.Frame(cmd, data))
        bits_at[round(t, 1)] = rp.parse_radar_mark(sim.payload(rp.CMD_RADAR_MARK))["enemy_1_vulnerable"]
    hero = sim.robots["blue_1"]
    # +5/s from 0: 100 at 20 s (first tick after 0 s), not before
    assert not bits_at[19.8] and bits_at[20.0] and bits_at[40.0]
    assert hero.max_progress == pytest.approx(150.0)  # capped at 150 (reached at 30 s)
    # marks stop at 40 s, held 1 s, then -10/s: 150 -> 100 at 46 s, vulnerable until then
    assert bits_at[45.8] and not bits_at[46.4]
    assert hero.vulnerable_s == pytest.approx(46.0 - 20.0, abs=0.25)
    assert sim.robots["blue_3"].vulnerable_s == 0 and sim.robots["blue_3"].unsent_s == pytest.approx(60.0, abs=0.11)
    s = sim.summary()
    assert [x["robot"] for x in s["robots"]] == ["blue_1", "blue_2", "blue_3", "blue_4", "blue_6", "blue_7"]  # the 2026 layout's slots
    row = next(x for x in s["robots"] if x["robot"] == "blue_1")
    assert row["vulnerable_frac"] == pytest.approx(26.0 / 60.0, abs=0.005)
    assert row["score"] == pytest.approx(5 * row["correct_s"] - 10 * (row["wrong_s"] + row["unsent_s"]), abs=0.2)


def test_2024_progress_bytes_and_a_stale_mark_on_a_moving_robot_turns_wrong():
    lines = [{"t": k / 30, "robots": [{"label": "blue_7", "p_field": [5.0 + 1.5 * k / 30, 7.0, 0]}]} for k in range(30 * 20)]
    truth = Truth.from_lines(lines)
    sim = RefereeSim(rules(2024), truth, mark_hold_s=5.0)
    sim.receive(0.0, rp.Frame(rp.CMD_MAP, rp.map_payload(2024, {7: (5.0, 7.0)})[0]))
    sim.advance(5.0)
    sc = sim.robots["blue_7"]
    # correct while the robot is within 0.6 m of the frozen mark (0.4 s at 1.5 m/s), wrong after, expired after 5 s
    assert sc.correct_s == pytest.approx(0.4, abs=0.11) and sc.wrong_s == pytest.approx(4.6, abs=0.11)
    assert len(sim.payload(rp.CMD_RADAR_MARK)) == 6 and sim.payload(rp.CMD_RADAR_MARK)[5] == int(round(sc.progress))


def test_absent_robot_marks_are_wrong_and_its_unmarked_time_is_not_scored():
    truth = static_truth({"blue_4": (12.0, 7.0)}, duration=20.0, absent={"blue_4": (5.0, 15.0)})
    sim = RefereeSim(rules(2024), truth)
    play(sim, lambda t: [(rp.CMD_MAP, rp.map_payload(2024, {4: (12.0, 7.0)})[0])] if t < 10 else [], 20.0)
    sc = sim.robots["blue_4"]
    assert sc.correct_s == pytest.approx(5.0, abs=0.15)  # 0..5 s on the field
    assert sc.wrong_s == pytest.approx(6.0, abs=0.25)  # 5..10 s marked while gone, + 1 s hold
    assert sc.off_field_s == pytest.approx(4.0, abs=0.25)  # 11..15 s gone and not marked
    assert sc.unsent_s == pytest.approx(5.0, abs=0.15)  # back at 15 s, never marked again


def test_every_season_layout_decoded_by_the_simulators_own_decoder():
    hero = {1: (10.0, 7.5), 7: (20.0, 5.0)}
    for season in KNOWN_SEASONS:
        r = rules(season)
        payloads = rp.map_payload(season, hero, {1: (3.0, 4.0)}, "blue")
        marks = {}
        for p in payloads:
            chk = decode_map(r, p, "red")
            assert not chk.problems, (season, chk.problems)
            marks.update(chk.marks)
        got = {k: v for k, v in marks.items() if v is not None}
        assert set(got) == {"blue_1", "blue_7"}, season
        assert np.allclose(got["blue_1"], (10.0, 7.5)) and np.allclose(got["blue_7"], (20.0, 5.0))
        # a payload of another season's size is a layout error
        other = rp.map_payload(2026 if season < 2026 else 2024, hero, {}, "blue")[0]
        assert decode_map(r, other, "red").problems
    # the protocol document's example frames, through the package's frame codec and the simulator's decoder
    f = rp.parse_frame(bytes.fromhex(MAP_2024))
    assert decode_map(rules(2024), f.data, "red").marks["blue_1"] == (10.0, 7.5)
    f = rp.parse_frame(bytes.fromhex(MAP_SINGLE_2023))
    assert decode_map(rules(2023), f.data, "red").marks == {"blue_1": (10.0, 7.5)}
    assert decode_map(rules(2023), f.data, "blue").problems  # id 101 is an ally of a blue radar


def test_rate_and_byte_budgets_are_counted():
    truth = static_truth({"blue_1": (10.0, 7.0)}, duration=10.0)
    ok, fast = RefereeSim(rules(2024), truth), RefereeSim(rules(2024), truth)
    payload = rp.map_payload(2024, {1: (10.0, 7.0)})[0]
    for k in range(50):
        ok.receive(k * 0.1, rp.Frame(rp.CMD_MAP, payload))
    for k in range(100):
        fast.receive(k * 0.05, rp.Frame(rp.CMD_MAP, payload))
    assert ok.over_rate == 0 and fast.over_rate > 50 and fast.malformed == 0
    rng = np.random.default_rng(0)
    jitter, over = RefereeSim(rules(2024), truth), RefereeSim(rules(2024), truth)
    for k in range(100):  # 10 Hz with +-20 ms arrival jitter passes; 12 Hz (20 % over) does not
        jitter.receive(k * 0.1, rp.Frame(rp.CMD_MAP, payload), t_wall=k * 0.1 + rng.uniform(-0.02, 0.02))
        over.receive(k / 12, rp.Frame(rp.CMD_MAP, payload))
    assert jitter.over_rate == 0 and over.over_rate > 50
    big = RefereeSim(rules(2026), truth)
    content = bytes(100)
    for k in range(300):  # 300 x 115 bytes in 1 s: over the 5120 B/s link budget and the 30 Hz 0x0301 rate
        big.receive(k / 300, rp.Frame(rp.CMD_INTERACTION, rp.interaction_payload(0x0200, 9, 7, content)))
    assert big.over_link_budget > 0 and big.over_rate > 0
    bad = RefereeSim(rules(2026), truth)
    bad.receive(0.0, rp.Frame(rp.CMD_INTERACTION, rp.interaction_payload(0x0200, 109, 7, b"x")))  # blue radar id from a red radar
    bad.receive(0.0, rp.Frame(rp.CMD_INTERACTION, rp.interaction_payload(0x0121, 9, rp.SERVER_ID, b"\x01")))  # 1 byte: 2026 has 8
    bad.receive(0.0, rp.Frame(0x0999, b""))
    assert bad.malformed == 3 and bad.dv_used == 0


def test_double_vulnerability_counter_grants_queue_and_illegal_values():
    r = rules(2026)
    truth = static_truth({"blue_1": (10.0, 7.0)}, duration=120.0)
    sim = RefereeSim(r, truth, dv_grants=(5.0, 10.0, 15.0))

    def cmd(t, v):
        sim.advance(t)
        sim.receive(t, rp.Frame(rp.CMD_INTERACTION, rp.interaction_payload(0x0121, 9, rp.SERVER_ID, rp.radar_cmd_payload(2026, v))))

    cmd(2.0, 1)  # no chance yet
    assert sim.dv_refused == 1 and sim.dv_used == 0
    cmd(11.0, 1)  # the same value again: nothing new
    assert rp.parse_radar_info(sim.payload(rp.CMD_RADAR_INFO))["chances"] == 2  # two grants so far; a third would exceed 2
    cmd(12.0, 2)  # request: active until 42 s
    info = rp.parse_radar_info(sim.payload(rp.CMD_RADAR_INFO))
    assert sim.dv_used == 1 and info["enemy_double_vulnerable"] and info["encryption_level"] == 1
    cmd(20.0, 3)  # queued while active
    assert sim.dv_pending == 1
    sim.advance(43.0)
    assert sim.dv_used == 2 and sim.dv_active_until == pytest.approx(72.0)
    cmd(80.0, 5)  # a jump of 2: illegal
    assert sim.dv_illegal == 1 and sim.dv_granted == 3  # the 15 s grant came once the first chance was spent


def test_referee_frames_parse_with_radarcals_parsers():
    truth = static_truth({"blue_1": (10.0, 7.0), "red_1": (3.0, 3.0)}, duration=10.0)
    for season in KNOWN_SEASONS:
        sim = RefereeSim(rules(season), truth, team="blue")
        frames = dict(sim.due_frames(0.0))
        st = rp.RefereeState()
        for cmd, data in frames.items():
            st.update(rp.parse_frame(rp.pack_frame(cmd, data)))
        assert st.errors == 0 and st.team == "blue" and st.own_id == 109
        assert st.game.stage == 4 and st.game.remaining_s == 420
        assert (rp.CMD_RADAR_MARK in frames) == (season >= 2024)
        assert not sim.due_frames(0.05)  # nothing due again within 50 ms
        assert [c for c, _ in sim.due_frames(0.1)] == [rp.CMD_ROBOT_STATUS]


class _ScriptedPort:
    """A byte port that delivers one 2026 minimap frame every 4th read (radarcal marking blue_1 right)."""

    def __init__(self):
        self.reads = 0
        self.written = []
        self.dropped_writes = 0
        self.frame = rp.pack_frame(rp.CMD_MAP, rp.map_payload(2026, {1: (10.0, 7.0)}, {}, "blue")[0])

    def read(self):
        self.reads += 1
        return self.frame if self.reads % 4 == 1 else b""  # every 0.2 s of the test clock: 5 Hz

    def write(self, data):
        self.written.append(rp.parse_frame(data))


@pytest.mark.parametrize("speed", [1.0, 0.5])
def test_serve_maps_wall_time_to_the_match_clock(speed, tmp_path):
    from radarcal.synth.referee_serve import serve

    truth = static_truth({"blue_1": (10.0, 7.0)}, duration=2.0)
    sim = RefereeSim(rules(2026), truth)
    ticks = iter(np.arange(0, 100, 0.05))
    port = _ScriptedPort()
    res = serve(sim, port, tmp_path / "log.jsonl", end_margin_s=0.0, poll_s=0.0, clock=lambda: float(next(ticks)), speed=speed)
    s = res.summary
    assert res.started and res.stopped_by == "end of truth"
    assert s["match_s"] == pytest.approx(2.0) and s["robots"][0]["correct_s"] == pytest.approx(2.0, abs=0.11)
    assert res.wall_s == pytest.approx(2.0 / speed, abs=0.11)  # the match took 2 / speed wall seconds
    status = [f for f in port.written if f.cmd_id == rp.CMD_GAME_STATUS]  # 1 Hz on the wall clock
    assert len(status) == pytest.approx(2.0 / speed + 1, abs=1)
    assert s["link"]["malformed_total"] == 0 and s["link"]["over_rate"] == 0

"""Referee simulator core: the referee side of a match, scored against a replay's truth (no I/O).

:class:`RefereeSim` takes the frames radarcal sends (decoded with :class:`radarcal.runtime.referee.FrameParser`, the
package's one frame codec), checks each against the season's rules (:mod:`radarcal.runtime.referee_season`: 0x0305
layout and size, 0x0301 header / size / sender, 0x0121 content length, per-command rate, byte budgets), keeps each
enemy robot's current mark, and on a fixed tick (``tick_s``, match seconds) decides per robot

* **correct**: a mark younger than ``mark_hold_s`` lies within ``mark_radius_m`` of the robot's true position,
* **wrong**: a mark is held but too far, or the robot is not on the field,
* **unsent**: no mark while the robot is on the field (not scored while it is off the field too),

and moves the mark progress by the season's rates (``progress`` / ``progress_bits`` rules; vulnerable at
``vulnerable_at``), grants double-vulnerability chances at given match times and handles the 0x0121 counter
(raise by exactly 1 = one request; a request while one is active is queued; a value that drops or jumps is illegal).
It produces the frames the referee sends (0x0001 game status, 0x0201 robot status, 0x0003 HP, 0x020C mark feedback,
0x020E radar info) and a per-robot score table. Truth: :class:`Truth` from ``truth.jsonl`` lines (field metres).

Times: ``t`` arguments are match seconds on the replay's clock (the CLI maps wall time to it); budget and rate
checks use ``t_wall`` (the link's own clock), which defaults to ``t``.
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from radarcal.runtime import referee as rp
from radarcal.runtime.referee_season import SeasonRules

__all__ = ["Truth", "RefereeSim", "RobotScore", "FrameCheck", "decode_map", "ROBOT_STATUS_BYTES", "MAX_INTERACTION_FRAME"]

ROBOT_STATUS_BYTES = 13  # 0x0201 as the 2024 appendix lays it out (radarcal reads only byte 0, the robot id); UNCERTAIN for 2026
MAX_INTERACTION_FRAME = 127  # [S2]: a whole 0x0301 frame is at most 127 bytes
RATE_TOLERANCE_S = 0.03  # arrival jitter allowed when counting frames in a 1 s window (plus one frame: see _budget)


# --- truth -----------------------------------------------------------------------------------------------------------
@dataclass
class Truth:
    """True robot positions: ``t`` (T,) s, ``labels`` (R,), ``xy`` (T, R, 2) field metres (NaN: not on the field)."""

    t: np.ndarray
    labels: list[str]
    xy: np.ndarray

    @classmethod
    def from_lines(cls, lines) -> "Truth":
        """From parsed ``truth.jsonl`` lines (``{"t", "robots": [{"label", "p_field"}, ...]}``); a robot missing
        from a line is off the field at that time."""
        lines = list(lines)
        labels = sorted({r["label"] for d in lines for r in d.get("robots", [])})
        idx = {lb: i for i, lb in enumerate(labels)}
        t = np.array([float(d["t"]) for d in lines], float)
        xy = np.full((len(lines), len(labels), 2), np.nan)
        for k, d in enumerate(lines):
            for r in d.get("robots", []):
                xy[k, idx[r["label"]]] = np.asarray(r["p_field"], float)[:2]
        order = np.argsort(t, kind="stable")
        return cls(t[order], labels, xy[order])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    def at(self, t: float) -> np.ndarray:
        """(R, 2) positions at ``t`` (linear between frames; NaN when off the field at either neighbour or outside)."""
        if not len(self.t) or t < self.t[0] - 1e-9 or t > self.t[-1] + 1e-9:
            return np.full((len(self.labels), 2), np.nan)
        k = int(np.searchsorted(self.t, t, "right"))
        if k >= len(self.t):
            return self.xy[-1].copy()
        if k == 0:
            return self.xy[0].copy()
        t0, t1 = self.t[k - 1], self.t[k]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return self.xy[k - 1] * (1 - w) + self.xy[k] * w


# --- decoding what radarcal sends ------------------------------------------------------------------------------------
@dataclass
class FrameCheck:
    """One received frame, decoded: ``problems`` is empty for a frame that follows the season's rules."""

    cmd_id: int
    nbytes: int
    problems: list[str] = field(default_factory=list)
    marks: dict[str, tuple[float, float] | None] = field(default_factory=dict)  # enemy label -> xy (None: explicitly not sent)
    ally: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    sub_id: int | None = None
    radar_cmd: int | None = None

    def to_dict(self) -> dict:
        d = {"cmd": f"0x{self.cmd_id:04X}", "bytes": self.nbytes}
        if self.problems:
            d["problems"] = self.problems
        if self.marks:
            d["marks"] = {k: None if v is None else [round(v[0], 3), round(v[1], 3)] for k, v in self.marks.items()}
        if self.sub_id is not None:
            d["sub_id"] = f"0x{self.sub_id:04X}"
        if self.radar_cmd is not None:
            d["radar_cmd"] = self.radar_cmd
        return d


def _team_ids(team: str) -> tuple[str, int]:
    return ("blue" if team == "red" else "red"), (0 if team == "red" else 100)


def decode_map(rules: SeasonRules, data: bytes, team: str) -> FrameCheck:
    """Decode a 0x0305 payload by the season's layout (the simulator's own struct formats; slots from the table)."""
    chk = FrameCheck(rp.CMD_MAP, len(data) + rp.OVERHEAD)
    layout = rules.map_layout.value
    if len(data) != rules.map_bytes:
        chk.problems.append(f"0x0305: {len(data)} bytes, the {rules.season} layout {layout} has {rules.map_bytes}")
        return chk
    enemy_team = "blue" if team == "red" else "red"
    if rules.single_target:
        vals = struct.unpack("<Hfff" if layout == "single14" else "<Hff", data)
        rid, x, y = vals[0], vals[1], vals[2]
        base = 100 if enemy_team == "blue" else 0
        n = rid - base
        if not 1 <= n <= 7:
            chk.problems.append(f"0x0305: target id {rid} is not an enemy robot of a {team} radar")
        elif not (np.isfinite(x) and np.isfinite(y)):
            chk.problems.append(f"0x0305: non-finite position for id {rid}")
        else:
            chk.marks[f"{enemy_team}_{n}"] = (float(x), float(y))
        return chk
    enemy_slots, ally_slots = rules.map_slots
    cm = struct.unpack(f"<{len(data) // 2}H", data)
    for i, n in enumerate(enemy_slots + ally_slots):
        x, y = cm[2 * i], cm[2 * i + 1]
        xy = None if x == 0 and y == 0 else (x / 100.0, y / 100.0)
        (chk.marks if i < len(enemy_slots) else chk.ally)[f"{enemy_team if i < len(enemy_slots) else team}_{n}"] = xy
    return chk


# --- the simulator ---------------------------------------------------------------------------------------------------
@dataclass
class RobotScore:
    label: str
    correct_s: float = 0.0
    wrong_s: float = 0.0
    unsent_s: float = 0.0
    off_field_s: float = 0.0  # off the field and not marked (not scored)
    vulnerable_s: float = 0.0
    double_vulnerable_s: float = 0.0
    progress: float = 0.0
    max_progress: float = 0.0

    def score(self, rules: SeasonRules) -> float:
        return rules.score_correct_per_s.value * self.correct_s + rules.score_wrong_per_s.value * (self.wrong_s + self.unsent_s)


class RefereeSim:
    """The referee's state for one match. Feed :meth:`receive` with frames from radarcal, call :meth:`advance` with
    the match clock, send what :meth:`due_frames` returns, read :meth:`summary` at the end."""

    def __init__(self, rules: SeasonRules, truth: Truth, team: str = "red", match_s: float = 420.0, mark_hold_s: float = 1.0, tick_s: float = 0.1,
                 dv_grants: tuple[float, ...] = (), unix_time0: int = 1_780_000_000):  # fmt: skip
        if team not in ("red", "blue"):
            raise ValueError(f"team must be red or blue, got {team!r}")
        self.rules = rules
        self.truth = truth
        self.team = team
        self.enemy_team, _ = _team_ids(team)
        self.own_id = rp.robot_id(team, 9)
        self.match_s = float(match_s)
        self.mark_hold_s = float(mark_hold_s)
        self.tick_s = float(tick_s)
        self.unix_time0 = int(unix_time0)
        # the enemy robots a mark can name: the layout's slots (all-robots layouts), or every robot number (single target)
        slots = rules.map_slots[0] or (1, 2, 3, 4, 5, 6, 7)
        enemy = [f"{self.enemy_team}_{n}" for n in slots]
        self.robots = {lb: RobotScore(lb) for lb in enemy}
        self._listed = set(enemy) if rules.map_slots[0] else {lb for lb in enemy if lb in truth.labels}
        self._truth_idx = {lb: truth.labels.index(lb) for lb in enemy if lb in truth.labels}
        self.marks: dict[str, tuple[float, float, float]] = {}  # label -> (x, y, t received)
        self.t = 0.0  # match time integrated so far
        self.elapsed = 0.0
        # double vulnerability
        self.dv_grants = sorted(float(g) for g in dv_grants)
        self.dv_granted = self.dv_used = self.dv_refused = self.dv_illegal = 0
        self.dv_chances = 0
        self.dv_pending = 0
        self.dv_active_until = -1.0
        self.dv_events: list[tuple[float, str]] = []
        self._radar_cmd = 0
        # link checks
        self.frames_in = 0
        self.by_cmd: dict[int, int] = {}
        self.malformed = 0
        self.problems: dict[str, int] = {}
        self.over_rate = 0
        self.over_link_budget = 0
        self.over_interaction_budget = 0
        self.layout_checked = 0
        self._arrivals: dict[int, deque] = {}
        self._bytes: deque = deque()
        self._ibytes: deque = deque()
        self._next_due: dict[int, float] = {}

    # --- incoming ----------------------------------------------------------------------------------------------------
    def receive(self, t: float, frame: rp.Frame, t_wall: float | None = None) -> FrameCheck:
        """Check and apply one frame radarcal sent at match time ``t`` (``t_wall``: link clock for rate checks)."""
        t_wall = t if t_wall is None else t_wall
        self.frames_in += 1
        self.by_cmd[frame.cmd_id] = self.by_cmd.get(frame.cmd_id, 0) + 1
        if frame.cmd_id == rp.CMD_MAP:
            chk = decode_map(self.rules, frame.data, self.team)
            if not chk.problems:
                self.layout_checked += 1
                for lb, xy in chk.marks.items():
                    if xy is None:
                        self.marks.pop(lb, None)
                    else:
                        self.marks[lb] = (xy[0], xy[1], t)
        elif frame.cmd_id == rp.CMD_INTERACTION:
            chk = self._interaction(t, frame.data)
        else:
            chk = FrameCheck(frame.cmd_id, len(frame.data) + rp.OVERHEAD, [f"0x{frame.cmd_id:04X}: not a command a radar sends"])
        if chk.problems:  # decoding / layout problems (budget and rate problems are counted on their own)
            self.malformed += 1
        self._budget(t_wall, chk)
        if chk.problems:
            for p in chk.problems:
                key = p.split(":")[0]
                self.problems[key] = self.problems.get(key, 0) + 1
        return chk

    def _interaction(self, t: float, data: bytes) -> FrameCheck:
        chk = FrameCheck(rp.CMD_INTERACTION, len(data) + rp.OVERHEAD)
        if len(data) < 6:
            chk.problems.append(f"0x0301: {len(data)} bytes, shorter than its 6-byte header")
            return chk
        sub, sender, receiver = struct.unpack_from("<HHH", data)
        content = data[6:]
        chk.sub_id = sub
        if chk.nbytes > MAX_INTERACTION_FRAME or len(content) > self.rules.interaction_max_content.value:
            chk.problems.append(f"0x0301: frame {chk.nbytes} bytes / content {len(content)} bytes over {MAX_INTERACTION_FRAME} / {self.rules.interaction_max_content.value}")
        if sender != self.own_id:
            chk.problems.append(f"0x0301: sender {sender}, a {self.team} radar is {self.own_id}")
        if sub == 0x0121:
            want = self.rules.radar_cmd_bytes.value
            if want is None:
                chk.problems.append(f"0x0301 sub 0x0121: no radar command in season {self.rules.season}")
            elif len(content) != want:
                chk.problems.append(f"0x0301 sub 0x0121: {len(content)} content bytes, season {self.rules.season} has {want}")
            elif receiver != rp.SERVER_ID:
                chk.problems.append(f"0x0301 sub 0x0121: receiver 0x{receiver:04X}, expected the server 0x8080")
            else:
                chk.radar_cmd = content[0]
                self._radar_command(t, content[0])
        elif 0x0200 <= sub <= 0x02FF:
            own = range(1, 8) if self.team == "red" else range(101, 108)
            if receiver not in own:
                chk.problems.append(f"0x0301 sub 0x{sub:04X}: receiver {receiver} is not one of our robots")
        return chk

    def _radar_command(self, t: float, value: int) -> None:
        if value == self._radar_cmd:
            return  # the same counter again: nothing new (radarcal repeats its state)
        if value != self._radar_cmd + 1:
            self.dv_illegal += 1
            self.dv_events.append((t, f"illegal radar_cmd {self._radar_cmd} -> {value}"))
            return
        self._radar_cmd = value
        self._settle_dv(t)
        if self.dv_chances <= 0:
            self.dv_refused += 1
            self.dv_events.append((t, "request refused: no chance"))
        elif t < self.dv_active_until:
            self.dv_pending += 1
            self.dv_events.append((t, "request queued: one is active"))
        else:
            self._start_dv(t)

    def _start_dv(self, t: float) -> None:
        self.dv_chances -= 1
        self.dv_used += 1
        self.dv_active_until = t + float(self.rules.dv_duration_s.value or 0.0)
        self.dv_events.append((t, f"double vulnerability until {self.dv_active_until:.1f} s"))

    def _settle_dv(self, t: float) -> None:
        """Grants due by ``t`` and queued requests whose turn came."""
        while self.dv_grants and self.dv_grants[0] <= t:
            g = self.dv_grants.pop(0)
            if self.dv_chances < int(self.rules.dv_max_chances.value or 0):
                self.dv_chances += 1
                self.dv_granted += 1
                self.dv_events.append((g, "chance granted"))
        if self.dv_pending and t >= self.dv_active_until:
            self.dv_pending -= 1
            if self.dv_chances > 0:
                self._start_dv(max(t, self.dv_active_until))
            else:
                self.dv_refused += 1

    def _budget(self, t_wall: float, chk: FrameCheck) -> None:
        """Per-command rate and byte budgets over a sliding 1 s window of arrival times. Arrival times carry the
        link's and the reader's jitter, so one frame of slack is allowed: more than ``hz + 1`` frames, or more than
        the budget without the newest frame, within 1 s is a violation (a sender 20 % over its rate is caught)."""
        hz = {rp.CMD_MAP: self.rules.map_hz.value, rp.CMD_INTERACTION: self.rules.interaction_hz.value}.get(chk.cmd_id)
        win = 1.0 - RATE_TOLERANCE_S
        if hz:
            q = self._arrivals.setdefault(chk.cmd_id, deque())
            q.append(t_wall)
            while q and q[0] <= t_wall - win:
                q.popleft()
            if len(q) > hz + 1:
                self.over_rate += 1
                chk.problems.append(f"rate: {len(q)} 0x{chk.cmd_id:04X} frames within 1 s (limit {hz:g} Hz)")
        for q, limit, is_i in ((self._bytes, self.rules.link_bytes_per_s.value, False), (self._ibytes, self.rules.interaction_bytes_per_s.value, True)):
            if is_i and chk.cmd_id != rp.CMD_INTERACTION:
                continue
            q.append((t_wall, chk.nbytes))
            while q and q[0][0] <= t_wall - win:
                q.popleft()
            total = sum(n for _, n in q)
            if total - chk.nbytes > limit:
                if is_i:
                    self.over_interaction_budget += 1
                else:
                    self.over_link_budget += 1
                chk.problems.append(f"budget: {total} {'0x0301 ' if is_i else ''}bytes within 1 s (limit {limit})")

    # --- the clock ---------------------------------------------------------------------------------------------------
    def advance(self, t: float) -> None:
        """Integrate marks, progress and double vulnerability from the last tick up to match time ``t``."""
        end = min(float(t), self.match_s, float(self.truth.t[-1]) if len(self.truth.t) else 0.0)
        while self.t + self.tick_s <= end + 1e-9:
            self._tick(self.t + self.tick_s)

    def _tick(self, tau: float) -> None:
        dt = self.tick_s
        self._settle_dv(tau)
        dv = tau <= self.dv_active_until
        r = self.rules
        truth_xy = self.truth.at(tau)
        radius = float(r.mark_radius_m.value)
        for lb, sc in self.robots.items():
            k = self._truth_idx.get(lb)
            p = truth_xy[k] if k is not None else np.array([np.nan, np.nan])
            on_field = bool(np.all(np.isfinite(p)))
            m = self.marks.get(lb)
            held = m is not None and tau - m[2] <= self.mark_hold_s + 1e-9
            if held and on_field and np.hypot(m[0] - p[0], m[1] - p[1]) <= radius:
                sc.correct_s += dt
                up = True
            elif held:
                sc.wrong_s += dt
                up = False
            elif on_field:
                sc.unsent_s += dt
                up = False
            else:
                sc.off_field_s += dt
                up = False
            if r.has_progress:
                rate = r.progress_up_per_s.value if up else r.progress_down_per_s.value
                sc.progress = float(np.clip(sc.progress + rate * dt, 0.0, r.progress_max.value))
                sc.max_progress = max(sc.max_progress, sc.progress)
                if sc.progress >= r.vulnerable_at.value:
                    sc.vulnerable_s += dt
                    if dv:
                        sc.double_vulnerable_s += dt
        self.t = tau
        self.elapsed = tau

    # --- outgoing ----------------------------------------------------------------------------------------------------
    def vulnerable(self, label: str) -> bool:
        r = self.rules
        return r.has_progress and self.robots[label].progress >= r.vulnerable_at.value

    def stage(self, started: bool) -> int:
        if not started:
            return 3  # 5 s countdown until radarcal's first frame starts the match clock
        return 4 if self.t < min(self.match_s, self.truth.duration) else 5

    def due_frames(self, t_wall: float, started: bool = True) -> list[tuple[int, bytes]]:
        """The referee frames due at ``t_wall`` (link clock): 0x0001 1 Hz, 0x0201 10 Hz, 0x0003 3 Hz,
        0x020C / 0x020E 1 Hz (seasons that have them)."""
        r = self.rules
        periods = {rp.CMD_GAME_STATUS: 1.0, rp.CMD_ROBOT_STATUS: 0.1, rp.CMD_ROBOT_HP: 1.0 / 3.0}
        if r.mark_feedback_bytes.value:
            periods[rp.CMD_RADAR_MARK] = 1.0
        if r.radar_info_bytes.value:
            periods[rp.CMD_RADAR_INFO] = 1.0
        out = []
        for cmd, period in periods.items():
            due = self._next_due.get(cmd, t_wall)
            if t_wall + 1e-9 < due:
                continue
            self._next_due[cmd] = max(due + period, t_wall)  # keeps the rate; never a burst after a stall
            out.append((cmd, self.payload(cmd, started)))
        return out

    def payload(self, cmd: int, started: bool = True) -> bytes:
        r = self.rules
        if cmd == rp.CMD_GAME_STATUS:
            remaining = max(0, int(round(self.match_s - self.t))) if started else 5
            return struct.pack("<BHQ", 1 | (self.stage(started) << 4), remaining, self.unix_time0 + int(self.t))
        if cmd == rp.CMD_ROBOT_STATUS:
            return bytes([self.own_id]) + bytes(ROBOT_STATUS_BYTES - 1)
        if cmd == rp.CMD_ROBOT_HP:
            return self._hp()
        if cmd == rp.CMD_RADAR_MARK:
            if r.mark_feedback_bytes.value == 6:
                order = [f"{self.enemy_team}_{n}" for n in (1, 2, 3, 4, 5, 7)]
                return bytes(int(min(255, round(self.robots[lb].progress))) if lb in self.robots else 0 for lb in order)
            bits = 0
            for bit, n in ((0, 1), (1, 2), (2, 3), (3, 4), (4, 6), (5, 7)):
                lb = f"{self.enemy_team}_{n}"
                if lb in self.robots and self.vulnerable(lb):
                    bits |= 1 << bit
            return struct.pack("<H", bits)
        if cmd == rp.CMD_RADAR_INFO:
            v = self.dv_chances & 3 | (4 if self.t <= self.dv_active_until else 0)
            if r.season >= 2026:
                v |= 1 << 3  # own encryption level 1
            return bytes([v])
        raise ValueError(f"the referee simulator does not send 0x{cmd:04X}")

    def _hp(self) -> bytes:
        on = np.all(np.isfinite(self.truth.at(self.t)), axis=1) if self.truth.labels else np.zeros(0, bool)
        present = {lb for lb, o in zip(self.truth.labels, on) if o}

        def hp(lb: str) -> int:
            return 200 if lb in present else 0

        if self.rules.hp_bytes.value == 32:
            vals = [hp(f"{c}_{n}") for c in ("red", "blue") for n in (1, 2, 3, 4, 5, 7)]
            vals = vals[:6] + [1500, 5000] + vals[6:] + [1500, 5000]
            return struct.pack("<16H", *vals)
        ally = [hp(f"{self.team}_{n}") for n in (1, 2, 3, 4)]
        return struct.pack("<4Hh5H", *ally, 0, hp(f"{self.team}_7"), 1500, 5000, 1500, 5000)

    # --- results -----------------------------------------------------------------------------------------------------
    def summary(self) -> dict:
        r = self.rules
        match = max(self.elapsed, 1e-9)
        rows = []
        for lb, sc in self.robots.items():
            if lb not in self._listed and sc.wrong_s == 0:
                continue  # single target: a robot number never on the field and never marked
            rows.append({"robot": lb, "correct_s": round(sc.correct_s, 2), "wrong_s": round(sc.wrong_s, 2), "unsent_s": round(sc.unsent_s, 2),
                         "off_field_s": round(sc.off_field_s, 2),
                         "vulnerable_frac": round(sc.vulnerable_s / match, 4) if r.has_progress else None,
                         "double_vulnerable_s": round(sc.double_vulnerable_s, 2), "max_progress": round(sc.max_progress, 1) if r.has_progress else None,
                         "score": round(sc.score(r), 1)})  # fmt: skip
        return {"season": r.season, "team": self.team, "match_s": round(self.elapsed, 2), "robots": rows,
                "total": {"correct_s": round(sum(x["correct_s"] for x in rows), 2), "wrong_s": round(sum(x["wrong_s"] for x in rows), 2),
                          "score": round(sum(x["score"] for x in rows), 1)},
                "link": {"frames": self.frames_in, "by_cmd": {f"0x{k:04X}": v for k, v in sorted(self.by_cmd.items())}, "malformed": self.malformed,
                         "problems": dict(self.problems), "layout_checked": self.layout_checked, "over_rate": self.over_rate,
                         "over_link_budget": self.over_link_budget, "over_interaction_budget": self.over_interaction_budget},
                "double_vulnerability": {"granted": self.dv_granted, "used": self.dv_used, "refused": self.dv_refused, "illegal": self.dv_illegal,
                                         "chances_left": self.dv_chances, "events": [[round(t, 2), e] for t, e in self.dv_events]}}  # fmt: skip

"""What radarcal sends on the referee link at match time (issue #20): guesses for robots nobody sees, confirmed by the
referee's mark progress; a bandwidth scheduler that keeps every season's rates and byte budgets; the
double-vulnerability (0x0121) policies with their success check; the sentry message with the roster and the
sentry's liveness.

* :class:`ProgressView` reads 0x020C: per-robot progress (2024-2025), or the vulnerable bit at >= 100 (2026, with an
  estimate of the progress from what was sent; the rates are :mod:`radarcal.runtime.referee_season`'s).
* :class:`Guesser`: for an empty enemy slot, the most plausible candidate (an unlabelled track within reach of where
  that robot was last seen, Hungarian over slots x candidates), else its last position. A guess is kept while that
  robot's progress rises (or it is fully marked, or, with bits only, until its progress could have reached the bit);
  otherwise it is dropped, banned for ``ban_s`` and the slot pauses (doubling after each failure).
* :class:`Scheduler`: 0x0305 at the season's rate (single-target layouts: one robot per frame, by priority and age;
  multi-target layouts: every slot), 0x0301 at its rate with DV > sentry > hero, every frame inside the 0x0301 and
  the whole-link byte budgets over any 1 s window of the loop clock.
* :class:`DoubleVulnerability`: policies (match time, enemies in our half, operator key in 0x0303, dart hit in
  0x0105), each off unless configured; a request raises the counter by one (2026 semantics), resends the same value
  until 0x020E shows it worked (enemy under double vulnerability, or a chance used) or ``confirm_s`` passes.
* :class:`Marking` ties them to the loop: ``messages(res, team, state)`` per frame.

Pure apart from the clock the caller passes (the loop's frame time, seconds).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from radarcal.runtime import referee as rp
from radarcal.runtime import referee_season as rs
from radarcal.runtime.roster import EMPTY, PREDICTED, SEEN, Roster, RosterFrame, obs_from_robots, slot_labels

__all__ = ["key_code", "season_rules", "ProgressView", "Guess", "Guesser", "MapTarget", "Scheduler", "DoubleVulnerability", "SentryLiveness", "Marking",
           "GUESS"]  # fmt: skip

GUESS = "guess"
STATE_CODE = {SEEN: 1, PREDICTED: 2, GUESS: 3}


def key_code(key: str | int) -> int:
    """The 0x0303 key value for ``--dv-on-key``: one letter or digit -> its upper-case ASCII code (the referee's
    "general key value"; UNCERTAIN), or a number 0..255 written out (``"81"``)."""
    k = str(key).strip()
    if len(k) == 1 and k.isalnum() and k.isascii():
        return ord(k.upper())
    if k.isdigit() and 0 <= int(k) <= 255:
        return int(k)
    raise ValueError(f"expected one letter or digit, or a key code 0..255, got {key!r}")


def season_rules(season: int) -> rs.SeasonRules:
    """The season table's rules (seasons outside it take the nearest known one)."""
    return rs.rules(min(max(int(season), rs.KNOWN_SEASONS[0]), rs.KNOWN_SEASONS[-1]))


# --- mark progress ---------------------------------------------------------------------------------------------------
class ProgressView:
    """Per enemy robot number: the progress the referee reported (2024-2025), the vulnerable bit (2026) and, with bits
    only, an estimate of the progress (up at the season's rate while a seen/predicted position is sent, down while
    not; clamped by the bit)."""

    def __init__(self, rules: rs.SeasonRules):
        self.rules = rules
        self.kind = rules.mark_rule.value  # distance | progress | progress_bits
        self.full = float(rules.progress_max.value or 100)
        self.vuln = float(rules.vulnerable_at.value or 100)
        self.up = float(rules.progress_up_per_s.value or 5.0)
        self.down = float(rules.progress_down_per_s.value or -10.0)
        self.progress: dict[int, float] = {}
        self.vulnerable: dict[int, bool] = {}
        self.estimate: dict[int, float] = {}
        self.updates = 0  # 0x020C frames read
        self.t_update = -np.inf
        self._seen_frames = 0
        self._t: float | None = None

    @property
    def has_feedback(self) -> bool:
        return self.kind != "distance" and self.updates > 0

    def observe(self, t: float, state) -> bool:
        """Read a new 0x020C from ``state`` (a RefereeState); True when there was one."""
        n = state.frames.get(rp.CMD_RADAR_MARK, 0) if state is not None else 0
        if n == self._seen_frames or not state.mark:
            return False
        self._seen_frames = n
        m = state.mark
        if "progress" in m:
            self.progress = {int(k): float(v) for k, v in m["progress"].items()}
            self.vulnerable = {k: v >= self.vuln for k, v in self.progress.items()}
            self.estimate = dict(self.progress)
        elif "bits" in m:
            bits = {1: 0, 2: 1, 3: 2, 4: 3, 6: 4, 7: 5}
            self.vulnerable = {k: bool(m["bits"] >> b & 1) for k, b in bits.items()}
            for k, v in self.vulnerable.items():
                e = self.estimate.get(k, 0.0)
                self.estimate[k] = max(e, self.vuln) if v else min(e, self.vuln - 1.0)
        self.updates += 1
        self.t_update = float(t)
        return True

    def advance(self, t: float, marked: set[int]) -> None:
        """Move the bit-season estimate to ``t``: robots in ``marked`` (a real position sent) up, the others down."""
        dt = 0.0 if self._t is None else max(0.0, float(t) - self._t)
        self._t = float(t)
        if self.kind != "progress_bits" or dt == 0:
            return
        for k in set(self.estimate) | set(marked):
            e = self.estimate.get(k, 0.0) + (self.up if k in marked else self.down) * dt
            self.estimate[k] = float(np.clip(e, 0.0, self.full))

    def value(self, number: int) -> float | None:
        """Reported progress (progress seasons) or the estimate (bits); None without feedback."""
        if not self.has_feedback:
            return None
        return self.progress.get(number) if self.kind == "progress" else self.estimate.get(number, 0.0)

    def fully_marked(self, number: int) -> bool:
        """At (within one second of) the progress ceiling: sending it can wait."""
        v = self.value(number)
        return v is not None and v >= self.full - self.up


# --- guessing --------------------------------------------------------------------------------------------------------
@dataclass
class Guess:
    slot: str
    key: str  # "track:<id>" or "last"
    xy: np.ndarray
    t0: float
    t_ok: float  # last time the progress confirmed it (t0 at start)
    trial_s: float
    p_last: float | None
    track_id: int | None = None
    confirmed: bool = False


@dataclass
class GuessStats:
    started: int = 0
    confirmed: int = 0
    dropped: int = 0
    guess_frames: int = 0


class Guesser:
    """Guesses for empty enemy slots (see the module text). ``vmax_mps`` bounds where a robot can be by now."""

    def __init__(self, progress: ProgressView, ban_s: float = 8.0, pause_s: float = 5.0, pause_max_s: float = 60.0, margin_s: float = 2.5,
                 latency_s: float = 0.3, blind_s: float = 5.0, bits_trial_max_s: float = 8.0, vmax_mps: float = 3.0, reach_margin_m: float = 1.0, max_reach_m: float = 6.0, last_s: float = 3.0):  # fmt: skip
        self.progress = progress
        self.ban_s, self.pause_s, self.pause_max_s = float(ban_s), float(pause_s), float(pause_max_s)
        self.margin_s = float(margin_s)  # 0x020C comes at 1 Hz: the longest wait for a decision (two reports + latency)
        self.latency_s = float(latency_s)  # link latency: a report this soon after a guess started does not reflect it
        self.blind_s = float(blind_s)  # without mark feedback a guess lasts this long
        self.bits_trial_max_s = float(bits_trial_max_s)  # bits only: longest wait for the bit a right guess would raise
        self.vmax, self.reach_margin, self.max_reach = float(vmax_mps), float(reach_margin_m), float(max_reach_m)
        # a robot's last position is a plausible guess this long after its last measurement (unless the progress
        # confirms it): measured on generated matches, a moving robot is metres away from it after that
        self.last_s = float(last_s)
        self.guesses: dict[str, Guess] = {}
        self.bans: dict[tuple[str, str], float] = {}
        self.paused_until: dict[str, float] = {}
        self.fails: dict[str, int] = {}
        self.stats = GuessStats()
        self.log: list[tuple[float, str, str, str]] = []  # (t, slot, key, event)

    def _trial(self, number: int) -> float:
        pv = self.progress
        if not pv.has_feedback:
            return self.blind_s
        if pv.kind == "progress_bits":
            e = pv.estimate.get(number, 0.0)
            if pv.vulnerable.get(number):
                return self.margin_s
            return min(max(0.0, (pv.vuln - e) / max(pv.up, 1e-6)), self.bits_trial_max_s) + self.margin_s
        return self.margin_s + 1.0  # no report at all for this long: drop

    def _end(self, t: float, g: Guess, event: str, ban: bool) -> None:
        self.guesses.pop(g.slot, None)
        self.log.append((t, g.slot, g.key, event))
        if ban:
            self.stats.dropped += 1
            self.bans[(g.slot, g.key)] = t + self.ban_s
            n = self.fails.get(g.slot, 0) + 1
            self.fails[g.slot] = n
            # the pause doubles with each failure in a row and is never shorter than the failed guess lasted, so
            # guesses of a robot that is not there take at most half of its absence, less and less as it goes on
            self.paused_until[g.slot] = t + min(max(self.pause_s * 2 ** (n - 1), t - g.t0), self.pause_max_s)

    def _confirm(self, t: float, g: Guess) -> None:
        g.t_ok, g.trial_s = t, self.margin_s
        if not g.confirmed:
            g.confirmed = True
            self.stats.confirmed += 1
            self.fails[g.slot] = 0

    def _check(self, t: float, g: Guess, number: int, fresh: bool) -> bool:
        """Keep (True) or drop the guess on the mark progress.

        Progress seasons: the first 0x020C at least ``latency_s`` after the guess started is the reference; each later
        one must show the progress higher than the one before (or at the ceiling), so a wrong guess is dropped at
        the second report, 1.3-2.3 s after it started. Bits: kept while the bit is set; without it, until the
        progress could have reached the bit (``trial_s``)."""
        pv = self.progress
        if fresh and pv.has_feedback:
            if pv.kind == "progress":
                p = pv.progress.get(number)
                if p is not None and t >= g.t0 + self.latency_s:
                    if p >= pv.full or (g.p_last is not None and p > g.p_last):
                        self._confirm(t, g)
                    elif g.p_last is not None:
                        g.p_last = p
                        return False
                    g.p_last = p
            elif pv.kind == "progress_bits":
                if pv.vulnerable.get(number):
                    self._confirm(t, g)
                elif g.confirmed:
                    return False  # the bit fell: the progress went down under the guess
        return t - g.t_ok <= g.trial_s

    def update(self, t: float, frame: RosterFrame, fresh_mark: bool) -> dict[str, Guess]:
        """The guesses to send this frame (slot label -> :class:`Guess`)."""
        from scipy.optimize import linear_sum_assignment

        t = float(t)
        self.bans = {k: v for k, v in self.bans.items() if v > t}
        slots = {s.label: s for s in frame.slots if s.enemy}
        cands = {c.id: c for c in frame.candidates}
        # 1. the running guesses: still needed, still there, still confirmed by the progress?
        for lab, g in list(self.guesses.items()):
            s = slots.get(lab)
            if s is None or s.state != EMPTY or s.dead:
                self._end(t, g, "found" if s is not None and s.state != EMPTY else "dead", ban=False)
                continue
            if g.track_id is not None:
                c = cands.get(g.track_id)
                if c is None:
                    self._end(t, g, "candidate gone", ban=False)
                    continue
                g.xy = c.xy.copy()
            elif s.xy is not None:
                if not g.confirmed and t - s.t_seen > self.last_s:
                    self._end(t, g, "stale", ban=False)
                    continue
                g.xy = s.xy.copy()
            if not self._check(t, g, s.number, fresh_mark):
                self._end(t, g, "not confirmed", ban=True)
        # 2. (re)assign: slots without a guess, with an unconfirmed last-position guess (a track within reach is more
        # plausible) or with a track guess of a never-seen slot (it yields to a slot that knows where its robot was)
        def open_row(s) -> bool:
            g = self.guesses.get(s.label)
            if g is None:
                return self.paused_until.get(s.label, -np.inf) <= t
            return (g.track_id is None and not g.confirmed) or (g.track_id is not None and s.xy_seen is None and not g.confirmed)

        # with bits only (2026) a guess for a robot never seen could not be confirmed before its progress reached 100
        # from nothing (20 s at +5/s): no basis, no check, so no guess
        blind_ok = self.progress.kind != "progress_bits"
        rows = [s for s in slots.values() if s.state == EMPTY and not s.dead and (blind_ok or s.xy_seen is not None) and open_row(s)]
        kept = {g.track_id for lab, g in self.guesses.items() if g.track_id is not None and lab not in {s.label for s in rows}}
        free = [c for c in frame.candidates if c.id not in kept]
        pick: dict[str, object] = {}
        if rows and free:
            C = np.full((len(rows), len(free)), 1e6)
            for i, s in enumerate(rows):
                own = self.guesses.get(s.label)
                for j, c in enumerate(free):
                    if (s.label, f"track:{c.id}") in self.bans:
                        continue
                    if s.xy_seen is None:
                        C[i, j] = 50.0  # never seen: anywhere, after every slot with a history
                    else:
                        d = float(np.linalg.norm(c.xy - s.xy_seen))
                        reach = min(self.vmax * max(t - s.t_seen, 0.0) + self.reach_margin, self.max_reach)
                        if d <= reach:
                            C[i, j] = d
                    if own is not None and own.track_id == c.id and C[i, j] < 1e6:
                        C[i, j] -= 0.5  # hysteresis: keep the guess it has
            r, cc = linear_sum_assignment(C)
            for i, j in zip(r, cc):
                if C[i, j] < 1e6:
                    pick[rows[i].label] = free[j]
        for s in rows:
            c = pick.get(s.label)
            own = self.guesses.get(s.label)
            if own is not None:
                if c is None or own.track_id == c.id:
                    continue  # no better candidate: keep what it has
                self._end(t, own, "switched", ban=False)
            if c is not None:
                g = Guess(s.label, f"track:{c.id}", c.xy.copy(), t, t, self._trial(s.number), None, c.id)
            elif s.xy is not None and (s.label, "last") not in self.bans and t - s.t_seen <= self.last_s:
                g = Guess(s.label, "last", s.xy.copy(), t, t, self._trial(s.number), None)
            else:
                continue
            self.guesses[s.label] = g
            self.stats.started += 1
            self.log.append((t, s.label, g.key, "start"))
        self.stats.guess_frames += len(self.guesses)
        return dict(self.guesses)


# --- bandwidth -------------------------------------------------------------------------------------------------------
@dataclass
class MapTarget:
    number: int
    xy: np.ndarray
    state: str  # seen | predicted | guess
    fully_marked: bool = False

    @property
    def priority(self) -> int:
        """3 seen, 2 predicted, 1 guess, 0 fully marked (sent only when nothing else waits)."""
        return 0 if self.fully_marked else {SEEN: 3, PREDICTED: 2, GUESS: 1}.get(self.state, 1)


@dataclass
class Interaction:
    key: int  # 0x0301 sub-id (the link's mailbox key)
    data: bytes  # the whole 0x0301 data (header + content)
    hz: float
    priority: int  # higher first


class Scheduler:
    """Decides which frames go out this loop frame so that, on the loop clock, 0x0305 keeps ``map_hz``, 0x0301 keeps
    ``interaction_hz`` (the whole cmd_id) and its byte budget, and every frame (9 bytes overhead included) fits the
    link budget over any 1 s window."""

    def __init__(self, rules: rs.SeasonRules, enemy_team: str = "blue"):
        self.rules = rules
        self.enemy_team = enemy_team
        self.map_dt = 1.0 / float(rules.map_hz.value)
        self.int_dt = 1.0 / float(rules.interaction_hz.value)
        self.int_budget = int(rules.interaction_bytes_per_s.value)
        self.link_budget = int(rules.link_bytes_per_s.value)
        self.layout = rules.map_layout.value
        self._win: deque[tuple[float, int, int]] = deque()  # (t, cmd, bytes)
        self._last: dict[int, float] = {}  # cmd -> t
        self._last_sub: dict[int, float] = {}  # 0x0301 sub-id -> t
        self._last_robot: dict[int, float] = {}  # single-target: robot number -> t
        self.sent: list[tuple[float, int, int]] = []  # (t, cmd, bytes) of everything scheduled (for tests / summary)
        self.keep_log = False
        self.frames = 0
        self.bytes = 0

    def _room(self, t: float, cmd: int, nbytes: int) -> bool:
        while self._win and t - self._win[0][0] >= 1.0:
            self._win.popleft()
        total = sum(n for _, _, n in self._win)
        if total + nbytes > self.link_budget:
            return False
        if cmd == rp.CMD_INTERACTION and sum(n for _, c, n in self._win if c == cmd) + nbytes > self.int_budget:
            return False
        return True

    def _due(self, t: float, last: float | None, dt: float) -> bool:
        return last is None or t - last >= dt - 1e-9

    def _take(self, t: float, cmd: int, data: bytes, key: int, out: list) -> None:
        n = len(data) + rp.OVERHEAD
        self._win.append((t, cmd, n))
        self._last[cmd] = t
        self.frames += 1
        self.bytes += n
        if self.keep_log:
            self.sent.append((t, cmd, n))
        out.append((cmd, data, key))

    def map_payload(self, t: float, enemy: list[MapTarget], ally: dict[int, np.ndarray]) -> bytes | None:
        """The 0x0305 data to send now (None: nothing to send)."""
        if self.layout.startswith("all"):
            if not enemy and not ally:
                return None
            return rp.map_payload(self.rules.season, {m.number: tuple(m.xy) for m in enemy}, {n: tuple(xy) for n, xy in ally.items()}, self.enemy_team, layout=self.layout)[0]
        if not enemy:
            return None
        best = max(enemy, key=lambda m: (m.priority > 0, t - self._last_robot.get(m.number, -1e9) + 0.5 * m.priority))
        self._last_robot[best.number] = t
        return rp.map_payload(self.rules.season, {best.number: tuple(best.xy)}, None, self.enemy_team, layout=self.layout)[0]

    def frame(self, t: float, enemy: list[MapTarget], ally: dict[int, np.ndarray], interactions: list[Interaction]) -> list[tuple[int, bytes, int]]:
        """(cmd_id, data, mailbox key) to send at loop time ``t``."""
        t = float(t)
        out: list[tuple[int, bytes, int]] = []
        if self._due(t, self._last.get(rp.CMD_MAP), self.map_dt):
            n_bytes = self.rules.map_bytes + rp.OVERHEAD
            if self._room(t, rp.CMD_MAP, n_bytes):
                data = self.map_payload(t, enemy, ally)
                if data is not None:
                    self._take(t, rp.CMD_MAP, data, 0, out)
        if self._due(t, self._last.get(rp.CMD_INTERACTION), self.int_dt):
            due = [m for m in interactions if self._due(t, self._last_sub.get(m.key), 1.0 / m.hz)]
            due.sort(key=lambda m: (-m.priority, self._last_sub.get(m.key, -1e9)))
            for m in due:
                if self._room(t, rp.CMD_INTERACTION, len(m.data) + rp.OVERHEAD):
                    self._last_sub[m.key] = t
                    self._take(t, rp.CMD_INTERACTION, m.data, m.key, out)
                    break
        return out


# --- double vulnerability --------------------------------------------------------------------------------------------
@dataclass
class DVRequest:
    reason: str
    t: float
    counter: int
    chances_before: int | None
    result: str = "pending"  # pending | ok | failed
    t_result: float | None = None


class DoubleVulnerability:
    """The 0x0121 policies (each None/False = off) and the request with its success check from 0x020E."""

    def __init__(self, rules: rs.SeasonRules, at_s: float | None = None, enemies_in_half: int | None = None, key: str | None = None, on_dart: bool = False,
                 match_s: float = 420.0, resend_s: float = 0.5, confirm_s: float = 3.0, cooldown_s: float = 5.0):  # fmt: skip
        self.rules = rules
        self.season = rules.season
        self.available = rules.radar_cmd_bytes.value is not None
        self.at_s = at_s
        self.enemies_in_half = enemies_in_half
        self.key = key_code(key) if key is not None else None
        self.on_dart = bool(on_dart)
        self.match_s, self.resend_s, self.confirm_s, self.cooldown_s = float(match_s), float(resend_s), float(confirm_s), float(cooldown_s)
        self.counter = 0
        self.requests: list[DVRequest] = []
        self.wanted: deque[tuple[str, float]] = deque()  # (reason, t) triggered, not yet requested
        self._fired_at = False
        self._was_in_half = False
        self._map_cmds = 0
        self._dart: tuple[int, int] | None = None
        self._dart_frames = 0
        self._last_send = -np.inf

    @property
    def enabled(self) -> bool:
        return self.available and (self.at_s is not None or self.enemies_in_half is not None or self.key is not None or self.on_dart)

    def match_time(self, state) -> float | None:
        """Seconds since the match started (0x0001 in stage 4: ``match_s`` minus the remaining time), else None."""
        g = state.game if state is not None else None
        if g is None or g.stage != 4:
            return None
        return self.match_s - float(g.remaining_s)

    def _triggers(self, t: float, state, enemies_in_our_half: int) -> None:
        mt = self.match_time(state)
        in_match = mt is not None
        if self.at_s is not None and not self._fired_at and in_match and mt >= self.at_s:
            self._fired_at = True
            self.wanted.append((f"match time {mt:.0f} s", t))
        if self.enemies_in_half is not None:
            now = enemies_in_our_half >= self.enemies_in_half
            if now and not self._was_in_half and in_match:
                self.wanted.append((f"{enemies_in_our_half} enemies in our half", t))
            self._was_in_half = now
        n = state.frames.get(rp.CMD_MAP_COMMAND, 0) if state is not None else 0
        if n != self._map_cmds:
            self._map_cmds = n
            if self.key is not None and state.map_command.get("key") == self.key and in_match:
                self.wanted.append((f"operator key {self.key}", t))
        n = state.frames.get(rp.CMD_DART_INFO, 0) if state is not None else 0
        if n != self._dart_frames and state.dart_raw:
            self._dart_frames = n
            d = rp.parse_dart_info(state.dart_raw, self.season)
            hit = (d["hit_target"], d["hits"])
            if self.on_dart and in_match and d["hit_target"] and self._dart is not None and hit != self._dart:
                self.wanted.append((f"dart hit target {d['hit_target']}", t))
            self._dart = hit

    def operator_request(self, t: float, reason: str = "console") -> None:
        """An operator's request from the live console (``LiveConsole.requests``)."""
        self.wanted.append((reason, float(t)))

    def update(self, t: float, state, enemies_in_our_half: int = 0) -> bytes | None:
        """The 0x0121 content to send now (None: nothing)."""
        if not self.available:
            return None
        t = float(t)
        self._triggers(t, state, enemies_in_our_half)
        info = state.radar_info if state is not None else {}
        cur = self.requests[-1] if self.requests else None
        if cur is not None and cur.result == "pending":
            ok = bool(info.get("enemy_double_vulnerable")) or (cur.chances_before is not None and "chances" in info and info["chances"] < cur.chances_before)
            if ok:
                cur.result, cur.t_result = "ok", t
            elif t - cur.t > self.confirm_s:
                cur.result, cur.t_result = "failed", t
            elif t - self._last_send >= self.resend_s:
                self._last_send = t
                return rp.radar_cmd_payload(self.season, self.counter)
            return None
        if not self.wanted:
            return None
        if cur is not None and t - cur.t < self.cooldown_s:
            return None
        if info.get("enemy_double_vulnerable") or info.get("chances", 1) == 0:
            if info.get("chances", 1) == 0:
                self.wanted.clear()  # nothing to spend: the trigger is lost, as a team's operator would see it
            return None  # active now: wait until it ends (a 2026 request meanwhile would queue a second chance)
        reason, _ = self.wanted.popleft()
        self.wanted.clear()
        self.counter = (self.counter + 1) & 0xFF
        self.requests.append(DVRequest(reason, t, self.counter, info.get("chances")))
        self._last_send = t
        return rp.radar_cmd_payload(self.season, self.counter)

    def summary(self) -> list[dict]:
        return [{"reason": r.reason, "t": round(r.t, 3), "counter": r.counter, "result": r.result} for r in self.requests]


# --- the sentry link -------------------------------------------------------------------------------------------------
class SentryLiveness:
    """When the sentry's last 0x0301 arrived (2026: the only robot that may send to the radar), on the loop clock."""

    def __init__(self, timeout_s: float = 2.0):
        self.timeout_s = float(timeout_s)
        self.sender: int | None = None
        self.count = 0
        self.t_rx: float | None = None

    def update(self, t: float, state, team: str) -> None:
        sid = rp.robot_id(team, 7)
        if sid != self.sender:
            self.sender, self.count = sid, 0
        n = state.interactions_from.get(sid, 0) if state is not None else 0
        if n != self.count:
            self.count, self.t_rx = n, float(t)
        self._t = float(t)

    def alive(self, t: float) -> bool:
        return self.t_rx is not None and t - self.t_rx <= self.timeout_s

    def text(self, t: float) -> str:
        if self.t_rx is None:
            return "sentry -"
        age = t - self.t_rx
        return f"sentry ok {age:.1f}s" if age <= self.timeout_s else f"sentry SILENT {age:.1f}s"


# --- the loop's side -------------------------------------------------------------------------------------------------
@dataclass
class MarkingStats:
    frames: int = 0
    sent_by_state: dict = field(default_factory=dict)  # seen / predicted / guess -> robot-frames put in the map


class Marking:
    """Per loop frame: roster -> guesses -> map targets, DV, sentry and hero messages -> the scheduler. ``cfg`` is a
    :class:`radarcal.runtime.config.RunConfig`."""

    def __init__(self, cfg, field_length_m: float = 28.0, sentry_hz: float = 5.0, hero_hz: float = 2.0, dv_hz: float = 2.0):
        self.cfg = cfg
        self.rules = season_rules(cfg.season)
        self.field_length = float(field_length_m)
        self.sentry_hz, self.hero_hz, self.dv_hz = float(sentry_hz), float(hero_hz), float(dv_hz)
        self.progress = ProgressView(self.rules)
        self.guesser = Guesser(self.progress, ban_s=cfg.guess_ban_s)
        self.dv = DoubleVulnerability(self.rules, cfg.dv_at_s, cfg.dv_enemies_in_half, cfg.dv_on_key, cfg.dv_on_dart)
        self.sentry = SentryLiveness()
        self.team: str | None = None
        self.roster: Roster | None = None
        self.scheduler: Scheduler | None = None
        self.last: RosterFrame | None = None
        self.last_guesses: dict = {}
        self.stats = MarkingStats()
        self._t = 0.0

    def _setup(self, team: str) -> None:
        enemy = "blue" if team == "red" else "red"
        enemy_n, ally_n = self.rules.map_slots
        if not enemy_n:  # single-target layouts: every robot that can be marked
            enemy_n = (1, 2, 3, 4, 5, 7)
        self.team = team
        self.roster = Roster(slot_labels(team, enemy_n, ally_n), enemy, hold_s=self.cfg.roster_hold_s if self.cfg.roster else 0.0, use_history=self.cfg.roster)
        if self.scheduler is None:
            self.scheduler = Scheduler(self.rules, enemy)
        self.scheduler.enemy_team = enemy  # a team change keeps the rate windows: no burst after it

    def _dead_numbers(self, state, enemy: str) -> set[int]:
        """Enemy robots the referee's HP says are dead (0x0003 with enemy HP, in the match)."""
        if state is None or not state.hp or not self.rules.hp_enemy_robots.value or state.game is None or state.game.stage != 4:
            return set()
        return {n for n in (1, 2, 3, 4, 5, 7) if state.hp.get(f"{enemy}_{n}") == 0}

    def messages(self, res, team: str, state=None, pipeline=None) -> list[tuple[int, bytes, int]]:
        """(cmd_id, data, mailbox key) to send for the frame result ``res`` (a FrameResult) at its time."""
        t = float(res.t)
        self._t = t
        if team != self.team:
            self._setup(team)
        enemy_team = "blue" if team == "red" else "red"
        frame = self.roster.update(t, obs_from_robots(res.robots))
        dead = self._dead_numbers(state, enemy_team)
        for s in frame.slots:
            if s.enemy and s.number in dead:
                s.dead = True
        fresh = self.progress.observe(t, state)
        guesses = self.guesser.update(t, frame, fresh) if self.cfg.guess and self.cfg.roster else {}
        self.last, self.last_guesses = frame, guesses
        targets: list[MapTarget] = []
        for s in frame.slots:
            if not s.enemy or s.dead:
                continue
            if s.state in (SEEN, PREDICTED) and s.xy is not None:
                targets.append(MapTarget(s.number, s.xy, s.state, self.progress.fully_marked(s.number)))
            elif s.label in guesses:
                targets.append(MapTarget(s.number, guesses[s.label].xy, GUESS, self.progress.fully_marked(s.number)))
        self.progress.advance(t, {m.number for m in targets if m.state != GUESS})
        for m in targets:
            self.stats.sent_by_state[m.state] = self.stats.sent_by_state.get(m.state, 0) + 1
        self.stats.frames += 1
        ally = frame.positions(enemy=False) if self.rules.map_slots[1] else {}
        self.sentry.update(t, state, team)
        radar = rp.robot_id(team, 9)
        inter: list[Interaction] = []
        if self.dv.available:
            half = sum(1 for m in targets if m.state != GUESS and ((m.xy[0] < self.field_length / 2) == (team == "red")))
            dv = self.dv.update(t, state, half)
            if dv is not None:
                inter.append(Interaction(rp.SUB_RADAR_CMD, rp.interaction_payload(rp.SUB_RADAR_CMD, radar, rp.SERVER_ID, dv), 1e6, 3))
        inter.append(Interaction(self.cfg.sentry_cmd_id, rp.interaction_payload(self.cfg.sentry_cmd_id, radar, rp.robot_id(team, 7), self.sentry_content(res, targets)),
                                 self.sentry_hz, 2))  # fmt: skip
        if res.hero_range_m is not None:
            inter.append(Interaction(self.cfg.hero_cmd_id, rp.interaction_payload(self.cfg.hero_cmd_id, radar, rp.robot_id(team, 1), rp.hero_range_content(res.hero_range_m)),
                                     self.hero_hz, 1))  # fmt: skip
        return self.scheduler.frame(t, targets, ally, inter)

    def operator_dv(self, args: dict | None = None) -> dict:
        """The console's ``double_vulnerability`` action (server thread): queue a request for the next frame."""
        if not self.dv.available:
            return {"queued": False, "reason": f"season {self.rules.season} has no 0x0121"}
        self.dv.operator_request(self._t, "console")
        return {"queued": True, "action": "double_vulnerability"}

    def sentry_content(self, res, targets: list[MapTarget]) -> bytes:
        """Guidance to the nearest enemy the roster locates (seen or predicted), then every enemy slot it sends."""
        s_xy = None
        if res.sentry is not None and res.sentry.get("sentry") is not None:
            s_xy = np.asarray(res.sentry["sentry"], float)[:2]
        real = [m for m in targets if m.state != GUESS]
        if s_xy is not None and real:
            d = np.array([m.xy - s_xy for m in real])
            k = int(np.argmin(np.linalg.norm(d, axis=1)))
            guide = rp.sentry_guidance_content(real[k].number, float(d[k, 0]), float(d[k, 1]), float(np.linalg.norm(d[k])))
        else:
            guide = rp.sentry_guidance_content(0, np.nan, np.nan, np.nan)
        return rp.sentry_roster_content(guide, [(m.number, STATE_CODE[m.state], float(m.xy[0]), float(m.xy[1])) for m in targets])

    def status_text(self) -> str:
        """Status-line part: slots seen/predicted/guessed, DV requests, sentry liveness."""
        if self.last is None:
            return ""
        en = [s for s in self.last.slots if s.enemy]
        seen = sum(s.state == SEEN for s in en)
        pred = sum(s.state == PREDICTED for s in en)
        txt = f" | roster {seen}+{pred}p+{len(self.last_guesses)}g/{len(en)}"
        if self.dv.requests:
            r = self.dv.requests[-1]
            txt += f" DV#{r.counter} {r.result}"
        return txt + " " + self.sentry.text(self._t)

    def summary(self) -> dict:
        g = self.guesser.stats
        return {"roster": self.cfg.roster, "guess": self.cfg.guess, "frames": self.stats.frames, "robot_frames_by_state": dict(self.stats.sent_by_state),
                "guesses": {"started": g.started, "confirmed": g.confirmed, "dropped": g.dropped},
                "scheduled": {"frames": self.scheduler.frames if self.scheduler else 0, "bytes": self.scheduler.bytes if self.scheduler else 0},
                "double_vulnerability": self.dv.summary(), "sentry_rx": self.sentry.count}  # fmt: skip


"""A fixed roster of robot slots (issue #20): one slot per enemy robot number (and per ally where the season sends
allies), tracks held in slots by their label history, never two tracks in one slot.

Each frame (:meth:`Roster.update`) every track adds its label evidence (the current label, else its decayed votes,
weighted by the frame interval) to its history per slot, and the history decays with ``history_tau_s``; the tracks
seen within ``lost_s`` are assigned to slots by the Hungarian method (:func:`scipy.optimize.linear_sum_assignment`)
on that history, so a few frames of a wrong label (a 3<->4 swap of the number classifier) do not move a robot to the
other slot. A slot whose robot nobody sees is *predicted* (its track's own prediction while the track lives, else
its last position moved on by its damped velocity) for ``hold_s`` after its last measurement, then *empty*.
Unlabelled tracks (LiDAR-first tracks no box has named) with no history in any slot are the *candidates* a guess
(:mod:`radarcal.runtime.marking`) may put into an empty slot.

``use_history=False`` is the per-frame baseline (``--no-roster``): a slot takes the track that carries its label in
this frame, as the pipeline gives it, with no hold of its own.

Pure: tracks in (:class:`TrackObs`, field frame metres, the loop's clock in seconds), :class:`RosterFrame` out.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

__all__ = ["TrackObs", "Slot", "RosterFrame", "Roster", "obs_from_robots", "slot_labels", "SEEN", "PREDICTED", "EMPTY"]

SEEN, PREDICTED, EMPTY = "seen", "predicted", "empty"


@dataclass
class TrackObs:
    """One track of this frame: ``id`` (stable across frames), ``label`` (None: unnamed), ``votes`` (label -> weight),
    field position ``xy`` (2,) m and velocity ``v`` (2,) m/s, ``seen`` (a measurement this frame), ``dead``."""

    id: int
    label: str | None
    xy: np.ndarray
    v: np.ndarray = field(default_factory=lambda: np.zeros(2))
    seen: bool = True
    votes: dict = field(default_factory=dict)
    dead: bool = False


def obs_from_robots(robots) -> list[TrackObs]:
    """:class:`TrackObs` from the pipeline's :class:`~radarcal.runtime.pipeline.RobotOut` list (box-path robots have
    no track id: a stable id from the label)."""
    out = []
    for r in robots:
        tid = r.track_id if r.track_id is not None else -(1 + zlib.crc32(str(r.label).encode()) % 1_000_000_000)
        v = np.asarray(r.velocity, float)[:2] if r.velocity is not None else np.zeros(2)
        out.append(TrackObs(int(tid), r.label, np.asarray(r.p_field, float)[:2].copy(), v, not r.predicted, dict(r.votes or {}), bool(r.dead)))
    return out


def slot_labels(team: str, enemy_numbers, ally_numbers=()) -> list[str]:
    """Slot labels: the enemy team's numbers then ours (``blue_1`` ... for a red station)."""
    enemy = "blue" if team == "red" else "red"
    return [f"{enemy}_{n}" for n in enemy_numbers] + [f"{team}_{n}" for n in ally_numbers]


@dataclass
class Slot:
    label: str
    number: int
    enemy: bool
    track_id: int | None = None
    xy: np.ndarray | None = None  # last known position (m), moved on while predicted
    xy_seen: np.ndarray | None = None  # where its track was last measured
    v: np.ndarray = field(default_factory=lambda: np.zeros(2))
    t_pos: float = -np.inf  # time of xy
    t_seen: float = -np.inf  # last frame its track had a measurement
    state: str = EMPTY
    dead: bool = False  # its robot was dead (grey armour, or no HP) when last known

    def to_dict(self) -> dict:
        d = {"label": self.label, "state": self.state, "track": self.track_id}
        if self.xy is not None and self.state != EMPTY:
            d["x"], d["y"] = round(float(self.xy[0]), 3), round(float(self.xy[1]), 3)
        if self.dead:
            d["dead"] = True
        return d


@dataclass
class RosterFrame:
    t: float
    slots: list[Slot]
    candidates: list[TrackObs]  # unlabelled, seen, in no slot

    def slot(self, label: str) -> Slot:
        return next(s for s in self.slots if s.label == label)

    def positions(self, enemy: bool = True, states=(SEEN, PREDICTED)) -> dict[int, np.ndarray]:
        """robot number -> xy of the slots in ``states`` (dead robots left out)."""
        return {s.number: s.xy for s in self.slots if s.enemy == enemy and s.state in states and s.xy is not None and not s.dead}


class Roster:
    """Fixed slots for ``labels`` (``"blue_3"``...); ``enemy_team`` tells which are enemies."""

    def __init__(self, labels: list[str], enemy_team: str, hold_s: float = 3.0, use_history: bool = True, history_tau_s: float = 5.0,
                 min_history_s: float = 0.1, lost_s: float = 0.4, stick: float = 0.25, velocity_tau_s: float = 1.0, flip_s: float = 0.5):  # fmt: skip
        self.slots = {lab: Slot(lab, int(lab.rsplit("_", 1)[1]), lab.startswith(enemy_team + "_")) for lab in labels}
        self.hold_s = float(hold_s)
        self.use_history = bool(use_history)
        self.history_tau_s = float(history_tau_s)
        self.min_history_s = float(min_history_s)  # labelled seconds a track needs before it can take a slot
        self.lost_s = float(lost_s)  # a track unseen this long no longer competes for slots
        self.stick = float(stick)  # fraction of its score the slot's current track gets as a bonus (hysteresis)
        self.velocity_tau_s = float(velocity_tau_s)
        self.history: dict[int, dict[str, float]] = {}
        self._t_track: dict[int, float] = {}  # track id -> last time it was seen
        self.flip_s = float(flip_s)  # a label (or no label) the labeller has kept this long is its decision, not a flip
        self._since: dict[int, tuple[str | None, float]] = {}  # track id -> (current label, since when)
        self._t: float | None = None

    # --- label history -------------------------------------------------------------------------------------------
    def _evidence(self, o: TrackObs, dt: float) -> None:
        # every label counts, slot or not: an ally the season sends no slot for is still no stranger
        h = self.history.setdefault(o.id, {})
        if o.label is not None:
            h[o.label] = h.get(o.label, 0.0) + dt
            return
        tot = sum(v for v in o.votes.values() if v > 0)
        if tot > 0:
            for lab, v in o.votes.items():
                if v > 0:
                    h[lab] = h.get(lab, 0.0) + 0.5 * dt * v / tot  # unnamed votes count half: the labeller did not decide

    def update(self, t: float, tracks: list[TrackObs]) -> RosterFrame:
        t = float(t)
        dt = 0.0 if self._t is None else float(np.clip(t - self._t, 0.0, 0.2))
        if self._t is not None and t > self._t:
            decay = np.exp(-(t - self._t) / self.history_tau_s)
            for h in self.history.values():
                for k in h:
                    h[k] *= decay
        self._t = t
        dt = dt if dt > 0 else 1.0 / 30.0
        for o in tracks:
            prev = self._since.get(o.id)
            if prev is None or prev[0] != o.label:
                self._since[o.id] = (o.label, t)
            if o.seen:
                self._t_track[o.id] = t
                self._evidence(o, dt)
            else:
                self._t_track.setdefault(o.id, t)
        live_ids = {o.id for o in tracks}
        for tid in [k for k, ts in self._t_track.items() if k not in live_ids and t - ts > 3 * self.history_tau_s]:
            self._t_track.pop(tid, None)
            self.history.pop(tid, None)
            self._since.pop(tid, None)
        by_id = {o.id: o for o in tracks}
        assign = self._assign_history(t, tracks) if self.use_history else self._assign_per_frame(tracks)
        taken = set(assign.values())
        for lab, s in self.slots.items():
            tid = assign.get(lab)
            o = by_id.get(tid) if tid is not None else None
            if o is not None:
                s.track_id = o.id
                s.dead = o.dead
                s.xy, s.v, s.t_pos = o.xy.copy(), o.v.copy(), t
                if o.seen:
                    s.t_seen, s.xy_seen = t, o.xy.copy()
                s.state = SEEN if o.seen else PREDICTED
                if not self.use_history:
                    continue
                if not o.seen and t - s.t_seen > self.hold_s and o.label != lab:
                    s.state = EMPTY
                continue
            if not self.use_history:  # per-frame: nobody carries the label now -> nothing to send
                s.state, s.track_id = EMPTY, None
                continue
            own = by_id.get(s.track_id) if s.track_id is not None else None
            if own is not None and own.id not in taken and not own.seen:
                s.xy, s.v, s.t_pos = own.xy.copy(), own.v.copy(), t  # its track still predicts it
            elif s.xy is not None and t > s.t_pos:
                dtp = t - s.t_pos
                k = self.velocity_tau_s * (1.0 - np.exp(-dtp / self.velocity_tau_s))  # damped: a lost robot slows down
                s.xy = s.xy + s.v * k
                s.v = s.v * np.exp(-dtp / self.velocity_tau_s)
                s.t_pos = t
            still = own is not None and own.id not in taken and own.label == lab  # the pipeline still predicts it by name
            if own is None or own.id in taken:
                s.track_id = None
            s.state = PREDICTED if s.xy is not None and (still or t - s.t_seen <= self.hold_s) else EMPTY
        held = {s.track_id for s in self.slots.values() if s.track_id is not None}
        cands = [o for o in tracks if o.seen and not o.dead and o.label is None and o.id not in held and self._unclaimed(o.id)]
        return RosterFrame(t, list(self.slots.values()), cands)

    def _stable(self, o: TrackObs, t: float) -> bool:
        """The track's current label (or lack of one) has lasted ``flip_s``: the labeller decided."""
        lab, since = self._since.get(o.id, (o.label, t))
        return lab == o.label and t - since >= self.flip_s

    def _unclaimed(self, tid: int) -> bool:
        """No slot history worth a slot (a named robot that lost its name for a moment is not a stranger; one unnamed
        for ``flip_s`` is: measured on generated matches, such a track was never its old robot any more)."""
        lab, since = self._since.get(tid, (None, -np.inf))
        if lab is None and self._t is not None and self._t - since >= self.flip_s:
            return True
        h = self.history.get(tid, {})
        return not h or max(h.values()) < self.min_history_s

    def _assign_history(self, t: float, tracks: list[TrackObs]) -> dict[str, int]:
        """Hungarian on the label history, with the labeller's stable decisions first: a track whose label has
        lasted ``flip_s`` takes that slot; a younger label takes it when the slot's track is not seen now; a track
        unnamed for ``flip_s`` holds no slot. Shorter flips are bridged by the history."""
        from scipy.optimize import linear_sum_assignment

        comp = [o for o in tracks if t - self._t_track.get(o.id, -np.inf) <= self.lost_s and not (o.label is None and self._stable(o, t))]
        labels = list(self.slots)
        if not comp:
            return {}
        holder_seen = {lab: any(o.id == s.track_id and o.seen for o in comp) for lab, s in self.slots.items()}
        # the pipeline handed the label over: the slot's track lost its name and a track with no past of its own took it
        handed = {lab: any(o.id == s.track_id and o.label is None for o in comp) for lab, s in self.slots.items()}
        S = np.zeros((len(comp), len(labels)))
        for i, o in enumerate(comp):
            h = self.history.get(o.id, {})
            stable = self._stable(o, t)
            for j, lab in enumerate(labels):
                S[i, j] = h.get(lab, 0.0)
                if self.slots[lab].track_id == o.id:
                    S[i, j] *= 1.0 + self.stick
                own_past = h.get(lab, 0.0) >= sum(v for k, v in h.items() if k != lab)
                if o.label == lab and o.seen and (stable or not holder_seen[lab] or (handed[lab] and own_past)):
                    S[i, j] += 1e3
        ok = S >= self.min_history_s
        cost = np.where(ok, -S, 1e6)
        r, c = linear_sum_assignment(cost)
        return {labels[j]: comp[i].id for i, j in zip(r, c) if ok[i, j]}

    def _assign_per_frame(self, tracks: list[TrackObs]) -> dict[str, int]:
        out: dict[str, int] = {}
        for o in sorted(tracks, key=lambda o: not o.seen):  # a seen carrier of a label before a predicted one
            if o.label in self.slots and o.label not in out:
                out[o.label] = o.id
        return out

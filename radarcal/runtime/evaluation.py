"""Accuracy of ``radarcal run`` against a replay's ``truth.jsonl`` (generated scenes with known truth).

Per frame, over the output robots and the true robots (``visible`` = some part seen by the camera):

* **located** / **missing** — a visible true robot has an output entry with its label (any distance; the 2024
  figures); **error** — horizontal distance of that entry (median, p95, max, by source);
* **right within 0.6 m** — that entry is within ``tol_m`` (0.6 m, the 2023 marking rule);
* **false robots** — entries that claim evidence (``source`` not ``predicted``) with no true robot (visible or
  not) within ``tol_m``; per frame;
* **wrong label** — claimed labelled entries within ``tol_m`` of a true robot of another label while the robot
  of their own label is not within ``tol_m``, as a fraction of claimed labelled entries;
* **any track within 0.3 m** (LiDAR only, labels ignored) over the robots the LiDAR sees (``lidar_hits`` >= 3 in
  the newest cloud, when the truth has it; else the visible ones);
* **ghosts** — the longest time an output track (by ``id``, else label) claims evidence while no true robot is
  within ``tol_m`` (the people at the boundary must not become robots).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from radarcal.io.replay import TruthLines

__all__ = ["Scorer", "evaluate_tracks", "OnlineEvaluator"]


class Scorer:
    def __init__(self, tol_m: float = 0.6, lidar_tol_m: float = 0.3, min_lidar_hits: int = 3):
        self.tol, self.lidar_tol, self.min_hits = float(tol_m), float(lidar_tol_m), int(min_lidar_hits)
        self.errors: list[float] = []
        self.sources: list[str] = []
        self.visible = self.missing = self.right = 0
        self.frames = self.claimed = self.false = self.labelled = self.wrong = 0
        self.lidar_visible = self.lidar_near = 0
        self._ghost_start: dict = {}
        self.ghost_max_s = 0.0
        self.ghost_key = None

    def add(self, t: float, out: list[dict], truth: dict) -> None:
        """``out``: dicts with label, x, y, source (and id); ``truth``: one line of truth.jsonl."""
        self.frames += 1
        rob = truth.get("robots", [])
        T = np.array([r["p_field"][:2] for r in rob], float).reshape(-1, 2)
        tl = [r["label"] for r in rob]
        O = np.array([[o["x"], o["y"]] for o in out], float).reshape(-1, 2)
        D = np.linalg.norm(O[:, None] - T[None], axis=2) if len(O) and len(T) else np.full((len(O), len(T)), np.inf)
        by_label = {o["label"]: i for i, o in enumerate(out) if o.get("label") is not None}
        for k, r in enumerate(rob):
            if r.get("visible", True):
                self.visible += 1
                i = by_label.get(r["label"])
                if i is None:
                    self.missing += 1
                else:
                    e = float(D[i, k])
                    self.errors.append(e)
                    self.sources.append(out[i]["source"])
                    self.right += e <= self.tol
            seen_by_lidar = r["lidar_hits"] >= self.min_hits if "lidar_hits" in r else r.get("visible", True)
            if seen_by_lidar:
                self.lidar_visible += 1
                self.lidar_near += bool(len(O) and D[:, k].min() <= self.lidar_tol)
        live = set()
        for i, o in enumerate(out):
            if o["source"] == "predicted":
                continue
            self.claimed += 1
            near = D[i] <= self.tol if len(T) else np.zeros(0, bool)
            key = o.get("id", o.get("label"))
            if not near.any():
                self.false += 1
                live.add(key)
                t0 = self._ghost_start.setdefault(key, t)
                if t - t0 > self.ghost_max_s:
                    self.ghost_max_s, self.ghost_key = t - t0, key
            if o.get("label") is not None:
                self.labelled += 1
                own = [k for k in range(len(tl)) if tl[k] == o["label"]]
                if near.any() and not any(near[k] for k in own):
                    self.wrong += 1
        for key in list(self._ghost_start):
            if key not in live:
                del self._ghost_start[key]

    def summary(self) -> dict:
        e, src = np.asarray(self.errors), np.asarray(self.sources)
        by = {s: {"n": int((src == s).sum()), "median_m": float(np.median(e[src == s]))} for s in sorted(set(self.sources))}
        pct = lambda a, b: 100.0 * a / b if b else None  # noqa: E731
        return {"visible": self.visible, "located": self.visible - self.missing, "missing": self.missing,
                "median_m": float(np.median(e)) if len(e) else None, "p95_m": float(np.percentile(e, 95)) if len(e) else None,
                "max_m": float(e.max()) if len(e) else None, "by_source": by,
                f"right_within_{self.tol:g}m_pct": pct(self.right, self.visible),
                "p95_all_visible_m": _p95_with_missing(e, self.visible),
                "false_per_frame": self.false / self.frames if self.frames else None, "wrong_label_pct": pct(self.wrong, self.labelled),
                f"lidar_within_{self.lidar_tol:g}m_pct": pct(self.lidar_near, self.lidar_visible), "lidar_visible": self.lidar_visible,
                "longest_ghost_s": self.ghost_max_s, "frames": self.frames}  # fmt: skip


def _p95_with_missing(e: np.ndarray, visible: int) -> float | None:
    """p95 of the error with every missing robot-frame counted as infinitely wrong: inf when the 95th percentile
    falls among the missing ones (``np.percentile`` interpolates inf - inf there and returns NaN with a warning)."""
    if not visible:
        return None
    full = np.sort(np.concatenate([e, np.full(visible - len(e), np.inf)]))
    k = 0.95 * (len(full) - 1)
    lo = int(np.floor(k))
    a, b, frac = float(full[lo]), float(full[min(lo + 1, len(full) - 1)]), k - lo
    return a if frac == 0 else np.inf if np.isinf(b) else a + (b - a) * frac


def _robot_dict(r) -> dict:
    return {"label": r.label, "x": float(r.p_field[0]), "y": float(r.p_field[1]), "source": r.source, "id": r.track_id if r.track_id is not None else r.label}


def evaluate_tracks(results: Iterable[dict], truth_by_frame: dict[str, dict], tol_m: float = 0.6) -> dict:
    """Scores of written results (``FrameResult.to_dict()`` lines) against ``truth.jsonl`` by frame name."""
    sc = Scorer(tol_m)
    for res in results:
        tr = truth_by_frame.get(res["frame"])
        if tr is not None:
            sc.add(float(res["t"]), [{**r, "id": r.get("id", r.get("label"))} for r in res["robots"]], tr)
    return sc.summary()


class OnlineEvaluator:
    """Scores while the loop runs (``on_frame`` callback), reading the truth lazily in frame order (flat memory on
    long replays: only floats are kept)."""

    def __init__(self, truth_path: Path, tol_m: float = 0.6):
        self._truth_lines = TruthLines(truth_path)
        self._pending: dict[str, dict] = {}
        self.scorer = Scorer(tol_m)

    def _truth(self, frame: str) -> dict | None:
        if frame in self._pending:
            return self._pending.pop(frame)
        for d in self._truth_lines:
            if str(d.get("frame")) == frame:
                return d
            self._pending[str(d.get("frame"))] = d
            if len(self._pending) > 1000:  # frames without results (e.g. --max-frames): do not hoard
                self._pending.pop(next(iter(self._pending)))
        return None

    def __call__(self, n: int, res) -> None:
        tr = self._truth(res.frame)
        if tr is not None:
            self.scorer.add(res.t, [_robot_dict(r) for r in res.robots], tr)

    def summary(self) -> dict:
        self._truth_lines.close()
        return self.scorer.summary()


def band_scores(results: Iterable[dict], truth_by_frame: dict[str, dict], origin_xy, min_range_m: float = 15.0, seen_by: str | None = None,
                tol_m: float = 0.6) -> dict:  # fmt: skip
    """Scores for the robots at least ``min_range_m`` (horizontal) from ``origin_xy`` (the station's camera), visible
    (to camera ``seen_by`` when the truth has ``visible_in``, issue #19), and for every frame:

    * ``p95_m`` / ``median_m``: horizontal error of the output entry carrying the robot's label (located ones; an
      entry with evidence before a ``predicted`` one of the same label);
    * ``correct_label_pct``: robot-frames whose own label is on an entry within ``tol_m``;
    * the same over the entries sent on the referee map only (labelled, with evidence this frame: not
      ``predicted``): ``p95_sent_m``, ``median_sent_m``, ``located_sent``, ``correct_label_sent_pct`` — a robot
      whose only entry is a prediction is not located there;
    * ``p95_visible_m`` / ``p95_visible_sent_m``: the same errors over **every** visible robot-frame of the band,
      an unlocated one counting as not within any error (inf): the error within which 95 % of the visible
      robot-frames are located (inf when fewer than 95 % are located at all); ``within_0p3_pct`` /
      ``within_0p3_sent_pct``: visible robot-frames whose label's entry is within 0.3 m;
    * ``tail_sources`` / ``tail_sources_sent``: the located errors by kind — the entry's ``source`` and the cameras
      the robot is visible in (``"depth cam0+cam1"``) — as ``(entries, their p95, share of the errors at or above
      the band's p95)``: where the tail comes from;
    * ``twice_pct``: frames in which some true robot (any range) has two output entries within ``tol_m`` that are
      nearer to it than to any other true robot — one robot reported twice; ``twice_labelled_pct``: the same
      counting only labelled entries with evidence this frame (those sent on the referee map)."""
    o = np.asarray(origin_xy, float)[:2]
    err, err_sent, n, right, right_sent, frames, twice, twice_named = [], [], 0, 0, 0, 0, 0, 0
    kind, kind_sent = [], []  # per located error: "<source> <cameras seeing the robot>" (the tail's make-up)
    for res in results:
        tr = truth_by_frame.get(res["frame"])
        if tr is None:
            continue
        frames += 1
        rob = tr.get("robots", [])
        T = np.array([r["p_field"][:2] for r in rob], float).reshape(-1, 2)
        O = np.array([[x["x"], x["y"]] for x in res["robots"]], float).reshape(-1, 2)
        D = np.linalg.norm(O[:, None] - T[None], axis=2) if len(O) and len(T) else np.full((len(O), len(T)), np.inf)
        sent = np.array([x.get("label") is not None and x.get("source") != "predicted" for x in res["robots"]], bool)  # what the referee map gets
        if len(O) and len(T):
            own = (D <= tol_m) & (D == D.min(axis=1, keepdims=True))
            twice += bool((own.sum(axis=0) >= 2).any())
            twice_named += bool((own[sent].sum(axis=0) >= 2).any())
        entry: dict[str, int] = {}  # label -> index of its entry, one with evidence first
        for i in sorted(range(len(O)), key=lambda i: not sent[i]):
            entry.setdefault(res["robots"][i].get("label"), i)
        for k, r in enumerate(rob):
            seen = (seen_by in r["visible_in"]) if (seen_by is not None and "visible_in" in r) else r.get("visible", True)
            if not seen or np.linalg.norm(T[k] - o) < min_range_m:
                continue
            n += 1
            i = entry.get(r["label"])
            if i is not None:
                err.append(float(D[i, k]))
                kind.append(f"{res['robots'][i].get('source')} {'+'.join(r.get('visible_in', [])) or '-'}")
                right += D[i, k] <= tol_m
                if sent[i]:
                    err_sent.append(float(D[i, k]))
                    kind_sent.append(kind[-1])
                    right_sent += D[i, k] <= tol_m
    e, es = np.asarray(err), np.asarray(err_sent)

    def pct(a, b):
        return 100.0 * a / b if b else None

    def tail_sources(e_located, kinds):
        """kind -> (entries, their p95, share of the entries at or above the band's p95)."""
        if not len(e_located):
            return {}
        kinds = np.asarray(kinds)
        tail = e_located >= np.percentile(e_located, 95)
        return {k: (int((kinds == k).sum()), float(np.percentile(e_located[kinds == k], 95)), float((tail & (kinds == k)).sum() / tail.sum())) for k in sorted(set(kinds))}

    def p95_counting_missing(e_located):
        return float(np.sort(np.r_[e_located, np.full(n - len(e_located), np.inf)])[int(np.ceil(0.95 * n)) - 1]) if n else None

    return {"robot_frames": n, "located": len(e), "median_m": float(np.median(e)) if len(e) else None, "p95_m": float(np.percentile(e, 95)) if len(e) else None,
            "correct_label_pct": pct(right, n), "located_sent": len(es), "median_sent_m": float(np.median(es)) if len(es) else None,
            "p95_sent_m": float(np.percentile(es, 95)) if len(es) else None, "correct_label_sent_pct": pct(right_sent, n),
            "p95_visible_m": p95_counting_missing(e), "p95_visible_sent_m": p95_counting_missing(es),
            "tail_sources": tail_sources(e, kind), "tail_sources_sent": tail_sources(es, kind_sent), "within_0p3_pct": pct(int((e <= 0.3).sum()), n), "within_0p3_sent_pct": pct(int((es <= 0.3).sum()), n),
            "twice_pct": pct(twice, frames), "twice_labelled_pct": pct(twice_named, frames), "frames": frames}  # fmt: skip

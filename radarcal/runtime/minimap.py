"""Minimap (top view of the field with robots and trails; unlabelled LiDAR tracks grey with "?", predictions
hollow) and the per-stage latency ring buffers of the status line."""

from __future__ import annotations

from typing import TYPE_CHECKING

import time

import numpy as np

from radarcal.teams import team_of, track_colours

if TYPE_CHECKING:
    from radarcal.runtime.pipeline import FrameResult

__all__ = ["Minimap", "StageTimer"]


def _colour(key: str, lighter: int = 0) -> tuple[int, int, int]:
    """BGR of a track: its team's shade for its robot number (:mod:`radarcal.teams`, the report's table too), grey
    for unlabelled tracks (``#id``) and other labels; ``lighter`` (0..255) blends it towards white for trails."""
    if team_of(key) is None:  # the table's greys are for white paper; the minimap is dark
        return (170 + lighter // 2,) * 3
    hex_rgb = track_colours([key])[key]
    r, g, b = (int(hex_rgb[i : i + 2], 16) for i in (1, 3, 5))
    w = min(max(lighter, 0), 255) / 255.0
    return tuple(int(round(c + (255 - c) * w)) for c in (b, g, r))


class Minimap:
    """Top view of the field (outline, raised areas, bases/outposts) with robots and their recent trails."""

    def __init__(self, field_model, size_m: tuple[float, float] = (28.0, 15.0), px_per_m: float = 30.0, trail_s: float = 2.0):
        import cv2

        self.field = field_model
        self.s = float(px_per_m)
        self.m = 20
        L, W = (field_model.size if field_model is not None else size_m)
        self.W, self.H = int(L * self.s) + 2 * self.m, int(W * self.s) + 2 * self.m
        base = np.full((self.H, self.W, 3), 40, np.uint8)
        if field_model is not None:
            cv2.fillPoly(base, [self._px(field_model.outline)], (70, 110, 70))
            for a in field_model.areas:
                g = int(np.clip(110 + 120 * a["z"], 0, 255))
                cv2.fillPoly(base, [self._px(a["polygon"])], (g - 30, g, g - 30))
            cv2.polylines(base, [self._px(field_model.outline)], True, (255, 255, 255), 2, cv2.LINE_AA)
            for name, p in field_model.landmarks.items():
                if name.endswith(("_base", "_outpost")):
                    c = (60, 60, 230) if name.startswith("red") else (230, 120, 40)
                    q = self._px(p[None, :2])[0]
                    cv2.rectangle(base, tuple(int(v) for v in q - 6), tuple(int(v) for v in q + 6), c, -1)
        else:
            cv2.rectangle(base, (self.m, self.m), (self.W - self.m, self.H - self.m), (255, 255, 255), 2)
        self.base = base
        self.trail_s = trail_s
        self.history: dict[str, list[tuple[float, float, float]]] = {}

    def _px(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.column_stack([self.m + xy[:, 0] * self.s, self.H - self.m - xy[:, 1] * self.s]).astype(np.int32)

    def draw(self, res: "FrameResult", full_trails: bool = False) -> np.ndarray:
        import cv2

        img = self.base.copy()
        for r in res.robots:
            self.history.setdefault(r.key, []).append((res.t, float(r.p_field[0]), float(r.p_field[1])))
        for key, hist in self.history.items():
            pts = [(x, y) for t, x, y in hist if full_trails or res.t - t <= self.trail_s]
            if len(pts) > 1:
                cv2.polylines(img, [self._px(np.array(pts))], False, _colour(key, 40), 1, cv2.LINE_AA)
        for r in res.robots:
            q = tuple(int(v) for v in self._px(r.p_field[None, :2])[0])
            cv2.circle(img, q, 8, _colour(r.key), -1 if r.source != "predicted" else 2, cv2.LINE_AA)
            text = r.label.split("_")[-1] if r.label else "?"
            cv2.putText(img, text, (q[0] + 9, q[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        cv2.putText(img, f"t={res.t:7.2f}s", (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        for label, hist in self.history.items():  # bounded memory
            if not full_trails and len(hist) > 400:
                del hist[:200]
        return img


class StageTimer:
    """Per-stage latency in fixed-size ring buffers (flat memory however long the match): the recent window feeds the
    status line, the last ``keep`` frames the summary percentiles."""

    def __init__(self, window: int = 60, keep: int = 4096):
        self.window = window
        self.keep = keep
        self.buf: dict[str, np.ndarray] = {}
        self.n: dict[str, int] = {}
        self.frame_times = np.zeros(window)
        self.frames = 0

    def add(self, timings: dict[str, float]) -> None:
        for k, v in timings.items():
            if k not in self.buf:
                self.buf[k] = np.zeros(self.keep)
                self.n[k] = 0
            self.buf[k][self.n[k] % self.keep] = v
            self.n[k] += 1
        self.frame_times[self.frames % self.window] = time.perf_counter()
        self.frames += 1

    def _values(self, k: str, last: int | None = None) -> np.ndarray:
        n = self.n[k]
        m = min(n, self.keep if last is None else min(last, self.keep))
        idx = (np.arange(n - m, n)) % self.keep
        return self.buf[k][idx]

    def fps(self) -> float:
        m = min(self.frames, self.window)
        if m < 2:
            return 0.0
        ft = self.frame_times[(np.arange(self.frames - m, self.frames)) % self.window]
        return (m - 1) / (ft[-1] - ft[0]) if ft[-1] > ft[0] else 0.0

    def recent(self) -> dict[str, float]:
        return {k: float(np.mean(self._values(k, self.window))) for k in self.buf if self.n[k]}

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for k in self.buf:
            v = self._values(k)
            if len(v):
                out[k] = {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(np.max(v))}
        return out

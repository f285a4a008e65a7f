"""Per-robot smoothing: one constant-velocity Kalman filter per label, with Mahalanobis outlier gating.

State ``[x, y, vx, vy]`` in the field frame; process noise = white acceleration of spectral density
``accel_sigma**2``; measurement = field (x, y) with the localiser's sigma. A measurement whose squared
Mahalanobis distance exceeds ``gate_chi2`` (default 13.8 = chi2(2) at 99.9 %) is rejected; after
``reinit_after`` consecutive rejections (1/3 s at 30 fps) the track is restarted at the measurement (the robot really is there:
a respawn, or a track that locked on a wrong detection); a depth measurement that disagrees with a track that never had
a depth fix (only ground-ray fixes) restarts it at once. Tracks unseen for ``max_coast_s`` are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Track", "TrackManager"]


@dataclass
class Track:
    label: str
    x: np.ndarray  # (4,) x, y, vx, vy
    P: np.ndarray  # (4,4)
    t: float  # time of the state
    t_update: float  # last accepted measurement
    source: str = "depth"
    rejected: int = 0  # consecutive gated-out measurements
    n_updates: int = 1
    n_rejected: int = 0
    n_depth: int = 0  # accepted LiDAR-depth fixes
    extra: dict = field(default_factory=dict)

    @property
    def xy(self) -> np.ndarray:
        return self.x[:2]

    @property
    def sigma(self) -> float:
        return float(np.sqrt(max(0.5 * (self.P[0, 0] + self.P[1, 1]), 0.0)))


class TrackManager:
    def __init__(self, accel_sigma: float = 3.0, gate_chi2: float = 13.8, reinit_after: int = 10, max_coast_s: float = 1.0, init_speed_sigma: float = 2.0):
        self.accel_sigma = float(accel_sigma)
        self.gate_chi2 = float(gate_chi2)
        self.reinit_after = int(reinit_after)
        self.max_coast_s = float(max_coast_s)
        self.init_speed_sigma = float(init_speed_sigma)
        self.tracks: dict[str, Track] = {}

    def _new(self, label: str, xy: np.ndarray, sigma: float, t: float, source: str) -> Track:
        P = np.diag([sigma**2, sigma**2, self.init_speed_sigma**2, self.init_speed_sigma**2])
        tr = Track(label, np.array([xy[0], xy[1], 0.0, 0.0]), P, t, t, source)
        self.tracks[label] = tr
        return tr

    def _predict(self, tr: Track, t: float) -> None:
        dt = t - tr.t
        if dt <= 0:
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.accel_sigma**2
        dt2, dt3 = dt * dt, dt * dt * dt
        Q1 = np.array([[dt3 / 3, dt2 / 2], [dt2 / 2, dt]]) * q
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = Q1
        Q[np.ix_([1, 3], [1, 3])] = Q1
        tr.x = F @ tr.x
        tr.P = F @ tr.P @ F.T + Q
        tr.t = t

    def update(self, t: float, measurements: list[tuple[str, np.ndarray, float, str]]) -> list[Track]:
        """``measurements``: (label, xy, sigma, source) of this frame (one per label). Returns the live tracks."""
        for label, xy, sigma, source in measurements:
            xy = np.asarray(xy, float)[:2]
            if not np.all(np.isfinite(xy)):
                continue
            sigma = float(sigma) if np.isfinite(sigma) and sigma > 0 else 0.3
            tr = self.tracks.get(label)
            if tr is None or t - tr.t_update > self.max_coast_s:
                self._new(label, xy, sigma, t, source).n_depth = int(source == "depth")
                continue
            self._predict(tr, t)
            R = np.eye(2) * sigma**2
            y = xy - tr.x[:2]
            S = tr.P[:2, :2] + R
            d2 = float(y @ np.linalg.solve(S, y))
            if d2 > self.gate_chi2:
                tr.rejected += 1
                tr.n_rejected += 1
                # a LiDAR-depth fix outranks a track that only ever had ground-ray fixes (terrain can hide a robot's
                # feet and pull the ground ray short by metres); otherwise restart after consistent rejections
                if tr.rejected >= self.reinit_after or (source == "depth" and tr.n_depth == 0):
                    self._new(label, xy, sigma, t, source).n_depth = int(source == "depth")
                continue
            K = tr.P[:, :2] @ np.linalg.inv(S)
            tr.x = tr.x + K @ y
            tr.P = (np.eye(4) - K[:, :2] @ np.eye(2, 4)) @ tr.P
            tr.P = 0.5 * (tr.P + tr.P.T)
            tr.t_update = t
            tr.rejected = 0
            tr.source = source
            tr.n_updates += 1
            tr.n_depth += source == "depth"
        for label in [k for k, tr in self.tracks.items() if t - tr.t_update > self.max_coast_s]:
            del self.tracks[label]
        for tr in self.tracks.values():
            self._predict(tr, t)
        return list(self.tracks.values())

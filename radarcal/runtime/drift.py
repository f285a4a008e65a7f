"""Drift monitor of ``radarcal run --drift-check-s S``: has the LiDAR moved on its mount during the match?

Every ``check_every_s`` seconds (cloud time) the points of the last ``window_s`` seconds are registered again to the
field's static geometry (:func:`radarcal.field.static_mesh`: the surface mesh, or the polygon field's triangulation,
plus the structure boxes) by robust point-to-plane ICP (:func:`radarcal.registration.robust_point_to_plane`; closest
points from a ``cKDTree`` over samples of the mesh, :class:`radarcal.registration.SurfaceSamples` — no open3d),
started from the pose the runtime uses, ``T_field_lidar`` (= ``T_field_cam · T_cam_lidar`` of the bundle). Only the
static points count: returns farther than the correspondence gate from the field (robots, people, the venue) are
rejected, and within the gate a Geman-McClure weight takes the rest down.

The check runs in a worker thread (``threaded=True``, what ``run`` does): the frame loop only appends a random
subsample of each cloud to a ring buffer (tens of microseconds), so frame latency never builds up; a check still
running when the next is due is simply not started. ``drift`` is the pose change from the reference: rotation
(deg) and displacement of the LiDAR origin (m); ``moved`` when either exceeds ``warn_deg`` / ``warn_m``.

Pure numeric core apart from the thread: arrays in, a :class:`DriftCheck` out. Frames: clouds in the LiDAR frame,
poses ``T_field_lidar``; metres and radians inside, degrees only in the reports.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from radarcal import geometry
from radarcal.registration import SurfaceSamples, point_to_plane_normal_matrix, robust_point_to_plane

__all__ = ["DriftConfig", "DriftCheck", "DriftMonitor", "check_drift", "static_target"]


@dataclass
class DriftConfig:
    check_every_s: float = 2.0          # cloud time between checks (``--drift-check-s``)
    window_s: float = 2.0               # points of the last window_s seconds are registered
    per_cloud_points: int = 2000        # random subsample kept of each cloud
    max_points: int = 8000              # points per check (a random subset of the window)
    min_points: int = 2000              # fewer points near the field: no verdict ("too few static points")
    gates_m: tuple[float, ...] = (0.4, 0.15, 0.06)
    iterations: int = 4
    warn_m: float = 0.02                # moved: displacement of the LiDAR origin above this ...
    warn_deg: float = 0.1               # ... or rotation above this
    confirm: int = 2                    # checks in a row over the threshold before the warning
    sample_spacing_m: float = 0.05      # mesh samples of the closest-point tree
    seed: int = 0


@dataclass
class DriftCheck:
    t: float                            # newest cloud time of the data registered (s)
    T_field_lidar: np.ndarray           # the registered pose
    deg: float                          # rotation from the reference
    m: float                            # displacement of the LiDAR origin from the reference
    sigma_deg: float                    # formal 1σ of the rotation / translation (a scale, not a test)
    sigma_m: float
    points: int                         # points within the finest gate
    moved: bool                         # over the threshold in this check
    seconds: float                      # wall time of the check
    dxyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # displacement in the field frame
    note: str = ""
    cpu_s: float = 0.0                  # CPU time of the check's thread (the first check includes building the target)

    def to_dict(self) -> dict:
        return {"t": round(self.t, 3), "deg": round(self.deg, 4), "cm": round(100 * self.m, 2), "sigma_deg": round(self.sigma_deg, 4),
                "sigma_cm": round(100 * self.sigma_m, 3), "points": self.points, "moved": self.moved, "seconds": round(self.seconds, 3), "cpu_s": round(self.cpu_s, 3),
                "dxyz_cm": [round(100 * v, 2) for v in self.dxyz_m], "note": self.note}  # fmt: skip


def static_target(field_model, spacing: float = 0.05) -> SurfaceSamples:
    """The closest-point target of the drift check: samples of :func:`radarcal.field.static_mesh` with normals."""
    from radarcal.field import static_mesh

    return SurfaceSamples.from_mesh(static_mesh(field_model), spacing)


def check_drift(points_lidar: np.ndarray, T_ref: np.ndarray, target: SurfaceSamples, cfg: DriftConfig, t: float = 0.0, T_start: np.ndarray | None = None,
                rng: np.random.Generator | None = None) -> DriftCheck:  # fmt: skip
    """Register ``points_lidar`` (N,3) to ``target`` from ``T_start`` (default ``T_ref``) and measure the pose change
    from ``T_ref``."""
    tic = time.perf_counter()
    rng = rng or np.random.default_rng(cfg.seed)
    P = np.asarray(points_lidar, float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) > cfg.max_points:
        P = P[rng.choice(len(P), cfg.max_points, replace=False)]
    T0 = np.asarray(T_ref if T_start is None else T_start, float)
    # the static points: near the field at the start pose (robots, people and the venue are farther)
    near = target.distance(P @ T0[:3, :3].T + T0[:3, 3], upper=cfg.gates_m[0]) < cfg.gates_m[0]
    P = P[near]
    if len(P) < cfg.min_points:
        return DriftCheck(t, T0, float("nan"), float("nan"), float("nan"), float("nan"), int(len(P)), False, time.perf_counter() - tic,
                          note=f"too few static points ({len(P)} within {cfg.gates_m[0]:.2f} m of the field)")  # fmt: skip
    T = robust_point_to_plane(P, T0, target, cfg.gates_m, cfg.iterations)
    H, s2, n_in = point_to_plane_normal_matrix(P, T, target, cfg.gates_m[-1])
    try:
        cov = s2 * np.linalg.inv(H + 1e-12 * np.eye(6))
        s_rot = float(np.degrees(np.sqrt(max(np.trace(cov[:3, :3]), 0.0))))
        # displacement of the origin t under the left perturbation: δt = v + ω × t  ->  A = [-[t]x, I]
        t0 = T[:3, 3]
        A = np.hstack([-np.array([[0, -t0[2], t0[1]], [t0[2], 0, -t0[0]], [-t0[1], t0[0], 0]]), np.eye(3)])
        s_pos = float(np.sqrt(max(np.trace(A @ cov @ A.T), 0.0)))
    except np.linalg.LinAlgError:
        s_rot = s_pos = float("inf")
    deg, m = geometry.pose_error(T, T_ref)
    moved = bool(deg > cfg.warn_deg or m > cfg.warn_m)
    return DriftCheck(t, T, deg, m, s_rot, s_pos, n_in, moved, time.perf_counter() - tic, tuple(float(v) for v in T[:3, 3] - np.asarray(T_ref)[:3, 3]))


class DriftMonitor:
    """Collects clouds (``add_cloud``), checks every ``check_every_s`` in a worker thread (or inline with
    ``threaded=False``), keeps the checks, and says when the LiDAR moved (``status_text``, ``summary``, ``snapshot``).

    ``field_model``: the bundle's :class:`radarcal.field.FieldModel`; ``T_field_lidar``: the pose the runtime uses.
    The target (mesh samples + tree, ~1 s) is built by the first check, off the loop."""

    def __init__(self, field_model, T_field_lidar: np.ndarray, cfg: DriftConfig | None = None, lidar: str = "lidar", threaded: bool = True,
                 on_warning=None):  # fmt: skip
        self.cfg = cfg or DriftConfig()
        self.field_model = field_model
        self.T_ref = np.asarray(T_field_lidar, float)
        self.lidar = lidar
        self.threaded = threaded
        self.on_warning = on_warning if on_warning is not None else (lambda text: sys.stderr.write(f"\nwarning: {text}\n"))
        self.checks: list[DriftCheck] = []
        self.warnings: list[str] = []
        self._buf: deque = deque()
        self._rng = np.random.default_rng(self.cfg.seed)
        self._target: SurfaceSamples | None = None
        self._last_t: float | None = None
        self._worker: threading.Thread | None = None
        self._lock = threading.Lock()
        self._over = 0
        self.moved = False
        self.first_warning_t: float | None = None
        self._last_ok_t: float | None = None  # time of the newest check within the threshold
        self.skipped_busy = 0
        self.error: str | None = None
        if threaded:  # build the target (mesh samples + tree, ~0.5 s of CPU) now, off the loop
            self._worker = threading.Thread(target=self._build_target, name="drift-target", daemon=True)
            self._worker.start()

    def _build_target(self) -> None:
        try:
            self._target = static_target(self.field_model, self.cfg.sample_spacing_m)
        except Exception as e:  # noqa: BLE001 - reported, never fatal
            self.error = f"{e.__class__.__name__}: {e}"


    # --- the loop's side (cheap) ----------------------------------------------------------------------------------
    def add_cloud(self, t: float, points: np.ndarray) -> None:
        """One cloud (LiDAR frame) at time ``t``: keep a random subsample; start a check when one is due."""
        P = np.asarray(points)
        if len(P) > self.cfg.per_cloud_points:
            P = P[self._rng.integers(0, len(P), self.cfg.per_cloud_points)]
        self._buf.append((float(t), np.asarray(P[:, :3], np.float32)))
        while self._buf and self._buf[0][0] < t - self.cfg.window_s:
            self._buf.popleft()
        if self._last_t is None:
            self._last_t = float(t)  # the first check once a whole window has been seen
            return
        if t - self._last_t < self.cfg.check_every_s:
            return
        if self._worker is not None and self._worker.is_alive():
            self.skipped_busy += 1
            return
        self._last_t = float(t)
        pts = np.concatenate([p for _, p in self._buf])
        if self.threaded:
            self._worker = threading.Thread(target=self._check, args=(pts, float(t)), name="drift-check", daemon=True)
            self._worker.start()
        else:
            self._check(pts, float(t))

    # --- the worker's side ----------------------------------------------------------------------------------------
    def _check(self, pts: np.ndarray, t: float) -> None:
        cpu0 = time.thread_time()
        try:
            if self._target is None:
                self._target = static_target(self.field_model, self.cfg.sample_spacing_m)
            last = self.checks[-1].T_field_lidar if self.checks and np.isfinite(self.checks[-1].deg) else None
            c = check_drift(pts, self.T_ref, self._target, self.cfg, t, T_start=last, rng=np.random.default_rng(self.cfg.seed + len(self.checks)))
        except Exception as e:  # noqa: BLE001 - a failing check must never stop the match loop; it is reported
            self.error = f"{e.__class__.__name__}: {e}"
            return
        c.cpu_s = time.thread_time() - cpu0
        with self._lock:
            self.checks.append(c)
            if not np.isfinite(c.deg):
                return
            self._over = self._over + 1 if c.moved else 0
            if not c.moved:
                self._last_ok_t = c.t
            if self._over >= self.cfg.confirm and not self.moved:
                self.moved = True
                self.first_warning_t = c.t
                when = (f"moved at t={self._last_ok_t:.1f}-{c.t:.1f} s" if self._last_ok_t is not None else
                        f"off since the start of the run (t={c.t:.1f} s): the bundle's pose is off or the station moved before the run")  # fmt: skip
                text = (f"{self.lidar} is {c.m * 100:.1f} cm / {c.deg:.2f} deg from the bundle's T_field_{self.lidar} (threshold {self.cfg.warn_m * 100:.0f} cm / "
                        f"{self.cfg.warn_deg:g} deg), {when}: recalibrate (radarcal lidar-field)")  # fmt: skip
                self.warnings.append(text)
                self.on_warning(text)
            elif self.moved and self._over == 0:
                self.moved = False
                text = f"{self.lidar} back within {self.cfg.warn_m * 100:.0f} cm / {self.cfg.warn_deg:g} deg of T_field_{self.lidar} at t={c.t:.1f} s"
                self.warnings.append(text)
                self.on_warning(text)

    def finish(self, timeout: float = 30.0) -> None:
        """Wait for a running check (end of a run: its result belongs in the summary)."""
        if self._worker is not None:
            self._worker.join(timeout)

    # --- reports --------------------------------------------------------------------------------------------------
    def status_text(self) -> str:
        """Part of the status line: `` | drift 0.3 cm 0.01° ok`` or `` | LIDAR MOVED 3.1 cm 0.30°``."""
        with self._lock:
            c = next((c for c in reversed(self.checks) if np.isfinite(c.deg)), None)
            moved = self.moved
        if c is None:
            return " | drift -" if self.error is None else " | drift ERROR"
        return f" | {'LIDAR MOVED' if moved else 'drift'} {c.m * 100:.1f} cm {c.deg:.2f}°{'' if moved else ' ok'}"

    def snapshot(self) -> dict:
        """Small dict for the console's health and the summary's last state."""
        with self._lock:
            c = self.checks[-1] if self.checks else None
            return {"moved": self.moved, "checks": len(self.checks), "last": c.to_dict() if c is not None else None, "error": self.error}

    def summary(self) -> dict:
        with self._lock:
            ok = [c for c in self.checks if np.isfinite(c.deg)]
            worst = max(ok, key=lambda c: max(c.m / self.cfg.warn_m, c.deg / self.cfg.warn_deg)) if ok else None
            return {"checks": len(self.checks), "check_every_s": self.cfg.check_every_s, "threshold_cm": 100 * self.cfg.warn_m, "threshold_deg": self.cfg.warn_deg,
                    "moved": self.moved, "first_warning_t": self.first_warning_t, "warnings": list(self.warnings),
                    "last": ok[-1].to_dict() if ok else None, "max": worst.to_dict() if worst else None,
                    "median_check_s": round(float(np.median([c.seconds for c in self.checks])), 3) if self.checks else None,
                    "median_check_cpu_s": round(float(np.median([c.cpu_s for c in self.checks])), 3) if self.checks else None,
                    "skipped_busy": self.skipped_busy, "error": self.error}  # fmt: skip

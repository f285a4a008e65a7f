"""Session file of ``radarcal radar-lidar``: :class:`RadarLidarSession` (kind ``radar_lidar``).

Frames: reflector centres in the main LiDAR frame (m); radar detections ``(x, y)`` in each radar's own scanning plane
(x forward, y left, m; the slant range as measured, frame-averaged); RCS in dBsm. The result (``T_<main>_<radar>``
with σ and the residual summary) lives in the bundle's transform entries; the session keeps what the report draws.
No solver is imported here, so the report can read it.

Array names (kept from the first version of the file): ``scene/<s>/lidar_centres`` (K,3), ``scene/<s>/radar/<r>``
(M,2), ``scene/<s>/rcs/<r>`` (M,), and per matched reflector of radar ``r``: ``radar/<r>/residual_m``,
``radar/<r>/holdout_m`` (leave-one-out, NaN for rejected ones), ``radar/<r>/radar_xy`` (R,2), ``radar/<r>/used`` (bool),
``radar/<r>/scene`` (scene name), ``radar/<r>/lidar_index`` (reflector index in that scene).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radarcal.sessions import SessionRecord

__all__ = ["RadarLidarSession"]


@dataclass
class RadarLidarSession(SessionRecord):
    KIND = "radar_lidar"
    ARRAY_DICT_KEYS = r"(scene|radar)/"

    T_lidar_G: np.ndarray | None = None  # ground frame (z up, on the fitted ground) -> main LiDAR
    by_name: dict[str, np.ndarray] = field(default_factory=dict)  # the scene/... and radar/... arrays (module docstring)
    model: str = ""  # slant | planar
    main_lidar: str = ""
    reference_radar: str = ""
    filter_counts: dict = field(default_factory=dict)  # scene -> {A, B, C}: detections after each patent filter
    quantisation: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    joint: dict = field(default_factory=dict)  # summary of the joint refinement
    detections: dict = field(default_factory=dict)  # scene -> radar -> [what each detection was taken for]

    # --- typed views of the per-name arrays ---------------------------------------------------------------------------
    def scenes(self) -> list[str]:
        return sorted({k.split("/")[1] for k in self.by_name if k.startswith("scene/")})

    def radars(self) -> list[str]:
        return sorted({k.split("/")[1] for k in self.by_name if k.startswith("radar/")})

    def lidar_centres(self, scene: str) -> np.ndarray:
        return np.asarray(self.by_name.get(f"scene/{scene}/lidar_centres", np.zeros((0, 3))), float).reshape(-1, 3)

    def radar_xy(self, scene: str, radar: str) -> np.ndarray:
        return np.asarray(self.by_name.get(f"scene/{scene}/radar/{radar}", np.zeros((0, 2))), float).reshape(-1, 2)

    def rcs(self, scene: str, radar: str) -> np.ndarray | None:
        v = self.by_name.get(f"scene/{scene}/rcs/{radar}")
        return None if v is None else np.asarray(v, float).ravel()

    def reflectors(self, radar: str) -> dict[str, np.ndarray]:
        """Per matched reflector of ``radar``: ``residual_m``, ``holdout_m``, ``radar_xy``, ``used`` and, when
        stored, ``scene`` and ``lidar_index``."""
        pre = f"radar/{radar}/"
        return {k[len(pre):]: v for k, v in self.by_name.items() if k.startswith(pre)}

    @classmethod
    def build(cls, T_lidar_G, lidar_centres: dict, radar_xy: dict, radar_rcs: dict, per_reflector: dict, **meta) -> RadarLidarSession:
        """From per-scene ``lidar_centres[s]``, ``radar_xy[s][r]``, ``radar_rcs[s][r]`` (None when absent) and
        ``per_reflector[r]`` (the solver's list of dicts: scene, lidar_index, radar_xy, residual_m,
        holdout_residual_m, used)."""
        a: dict[str, np.ndarray] = {}
        for s, c in lidar_centres.items():
            a[f"scene/{s}/lidar_centres"] = np.asarray(c, float).reshape(-1, 3)
        for s, per in radar_xy.items():
            for r, xy in per.items():
                a[f"scene/{s}/radar/{r}"] = np.asarray(xy, float).reshape(-1, 2)
        for s, per in (radar_rcs or {}).items():
            for r, v in (per or {}).items():
                if v is not None:
                    a[f"scene/{s}/rcs/{r}"] = np.asarray(v, float).ravel()
        for r, refl in per_reflector.items():
            a[f"radar/{r}/residual_m"] = np.array([p["residual_m"] for p in refl], float)
            a[f"radar/{r}/holdout_m"] = np.array([p["holdout_residual_m"] for p in refl], float)
            a[f"radar/{r}/radar_xy"] = np.array([p["radar_xy"] for p in refl], float).reshape(-1, 2)
            a[f"radar/{r}/used"] = np.array([p["used"] for p in refl], bool)
            a[f"radar/{r}/scene"] = np.array([str(p["scene"]) for p in refl], str)
            a[f"radar/{r}/lidar_index"] = np.array([int(p["lidar_index"]) for p in refl], int)
        return cls(T_lidar_G=np.asarray(T_lidar_G, float), by_name=a, **meta)

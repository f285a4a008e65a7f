"""Runtime settings of ``radarcal run``: :class:`RunConfig`, the one declaration of their defaults.

The bundle's ``runtime:`` section stores the ones a station tunes per match (``RunConfig.BUNDLE_KEYS`` maps bundle keys
to fields); :data:`radarcal.bundle.DEFAULT_RUNTIME`, what a new bundle lists, is derived from these defaults
(:meth:`RunConfig.bundle_defaults`). Light on purpose (no numpy): the bundle imports it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from radarcal.bundle import Bundle

__all__ = ["RunConfig", "LOCALISE_MODES"]

LOCALISE_MODES = ("auto", "lidar", "box")


@dataclass
class RunConfig:
    team: str = "red"  # our colour; the referee link (0x0201) overrides it when connected
    season: int = 2024
    robot_radius_m: float = 0.27
    visible_depth_factor: float = 0.85
    cloud_queue_points: int = 200_000
    cloud_queue_age_s: float = 1.0
    depth_max_age_s: float = 0.5  # oldest cloud a box depth may come from (robots move ~1.5 m/s)
    min_score: float = 0.25
    max_coast_s: float = 1.0
    accel_sigma: float = 3.0
    sentry_xy: tuple[float, float] | None = None  # fixed sentry position when it is not tracked
    sentry_cmd_id: int = 0x0200  # robot-to-robot sub-id of the sentry guidance message
    hero_cmd_id: int = 0x0201  # robot-to-robot sub-id of the hero range message
    hero_range_offset_m: float = 0.0
    surface_filter: bool = True  # drop LiDAR returns from the field surface before box depth
    surface_min_height_m: float = 0.08
    # on raised areas the height tolerance is at least this many times the calibration's range sigma (1.2: ~10 cm at 16 m
    # with 0.3 deg; measured 1.2 against 2 on `synth match` and the 2024 mesh replays, docs/runtime.md round 7)
    surface_raised_k_sigma: float = 1.2
    localise: str = "auto"  # auto | lidar | box
    cloud_sweep_s: float = 0.1  # firing duration of one cloud; the cloud's time is its arrival
    cloud_latency_s: float = 0.0  # sweep end -> arrival
    window_sweeps: int = 1  # clouds integrated before clustering (1 measured best: docs/runtime.md)
    learn_background: bool = True
    # auto: run the box path beside and output its track where no cluster explains a label (off: it gained 0-3.8 points
    # of right labels on `synth match` but raised the far-robot p95 on the `synth field` family, docs/runtime.md)
    box_shadow: bool = False
    ground_min_aspect: float = 0.55  # box height / width below which a LiDAR-first box-only fix takes no ground ray
    drift_check_s: float = 0.0  # re-register the LiDAR to the field every this many seconds (0: off; runtime/drift.py)
    # marking (radarcal.runtime.roster / marking, docs/runtime.md "Roster, guessing, bandwidth, double vulnerability")
    roster: bool = True  # fixed robot slots by label history (False: each frame's labels as they are)
    guess: bool = True  # send a guess for an empty slot, kept while that robot's mark progress rises
    roster_hold_s: float = 0.5  # a lost slot is predicted this long (longer while the pipeline predicts its track by name), then left empty
    guess_ban_s: float = 8.0  # a guess the mark progress did not confirm is not tried again for this long
    dv_at_s: float | None = None  # double vulnerability at this match time (s since the match started)
    dv_enemies_in_half: int | None = None  # ... when at least this many enemies are in our half
    dv_on_key: str | None = None  # ... on this key of the aerial operator's map command (0x0303)
    dv_on_dart: bool = False  # ... when our dart hits (0x0105)

    # bundle runtime key -> field (read by from_bundle)
    BUNDLE_KEYS = {"referee_season": "season", "robot_radius_m": "robot_radius_m", "cloud_queue_points": "cloud_queue_points", "cloud_queue_age_s": "cloud_queue_age_s",
                   "depth_max_age_s": "depth_max_age_s", "hero_range_offset_m": "hero_range_offset_m", "team": "team", "sentry_xy": "sentry_xy",
                   "cloud_sweep_s": "cloud_sweep_s", "cloud_latency_s": "cloud_latency_s"}  # fmt: skip
    # the keys a new bundle lists with their defaults (what a station edits per match)
    LISTED_IN_NEW_BUNDLES = ("hero_range_offset_m", "cloud_queue_points", "cloud_queue_age_s", "referee_season")

    @classmethod
    def bundle_defaults(cls) -> dict[str, Any]:
        """``{bundle key: default}`` of :attr:`LISTED_IN_NEW_BUNDLES` (the source of ``bundle.DEFAULT_RUNTIME``)."""
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        return {k: defaults[cls.BUNDLE_KEYS[k]] for k in cls.LISTED_IN_NEW_BUNDLES}

    @classmethod
    def from_bundle(cls, bundle: "Bundle", **overrides) -> "RunConfig":
        """The bundle's ``runtime:`` values over the defaults, then ``overrides`` (None = not given)."""
        rt = bundle.runtime or {}
        types = {f.name: type(f.default) for f in dataclasses.fields(cls)}
        cfg = cls()
        for key, name in cls.BUNDLE_KEYS.items():
            v = rt.get(key)
            if v is None:
                continue
            if name == "sentry_xy":
                v = tuple(float(x) for x in v)[:2]
            elif types[name] in (int, float, str):
                v = types[name](v)
            setattr(cfg, name, v)
        for k, v in overrides.items():
            if v is not None:
                setattr(cfg, k, v)
        return cfg

"""Simulated LiDAR scan patterns (unit ray directions in the LiDAR frame: x forward, y left, z up)."""

from __future__ import annotations

import numpy as np

__all__ = ["livox_rosette_dirs", "spinning_directions"]


def livox_rosette_dirs(t: np.ndarray, fov_deg: float = 70.4, rates_hz: tuple[float, float] = (121.57, -77.73), phase2: float = 0.3) -> np.ndarray:
    """Directions (N,3) at firing times ``t`` (N,) s of a two-prism Risley rosette (Livox Mid-70 style).

    Two deflections of a quarter of the full FoV angle rotate at incommensurate rates in opposite directions, so the
    pattern never repeats and fills the circular FoV more densely the longer it integrates."""
    t = np.asarray(t, float)
    a = 0.5 * np.deg2rad(fov_deg / 2)
    w1, w2 = 2 * np.pi * rates_hz[0], 2 * np.pi * rates_hz[1]
    px = a * (np.cos(w1 * t) + np.cos(w2 * t + phase2))
    py = a * (np.sin(w1 * t) + np.sin(w2 * t + phase2))
    theta = np.hypot(px, py)
    phi = np.arctan2(py, px)
    s = np.sin(theta)
    return np.stack([np.cos(theta), s * np.cos(phi), s * np.sin(phi)], axis=1)


def spinning_directions(beams: int, elevation_deg: tuple[float, float], duration_s: float, spin_hz: float, rate: float) -> np.ndarray:
    """Unit ray directions of a spinning multi-beam LiDAR (360 deg) firing ``rate`` points/s in total."""
    per_beam = max(1, int(rate * duration_s / beams))
    az = np.linspace(0, 2 * np.pi * spin_hz * duration_s, per_beam, endpoint=False)
    el = np.radians(np.linspace(elevation_deg[0], elevation_deg[1], beams))
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    az_g = az_g.ravel() + 1e-4 * np.arange(az_g.size) % 1e-3  # tiny dither so sweeps do not repeat exactly
    el_g = el_g.ravel()
    ce = np.cos(el_g)
    return np.stack([ce * np.cos(az_g), ce * np.sin(az_g), np.sin(el_g)], axis=1)

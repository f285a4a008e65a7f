"""Field models: the playing field as a data model (landmarks, outline, raised areas) — not a solver.

Field frame: origin at a field corner, x along the long side, y across, z up, metres. The surface is
piecewise flat: the ground plane z = 0 plus raised areas, each a polygon extruded from the ground up to its
top (a horizontal top at ``z``, or a sloped top ``z = a x + b y + c`` when the area has a ``plane`` — ramps).
Vertical walls join an area's top to the ground, so :meth:`FieldModel.intersect_rays` returns the first hit with
that solid (a low ray can hit a highland's side wall).

Optional ``structures`` (bases, outposts as oriented boxes) are for renderers and the scene generator; they are
not part of the surface that ``surface_z`` / ``intersect_rays`` describe.

The built-in ``rmuc2024`` model and every coordinate in it are documented and justified in ``docs/field.md``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radarcal.errors import InputError
from radarcal.plain import to_plain as _plain

__all__ = ["FieldModel", "load_field", "field_from_dict", "BUILTIN_FIELDS", "builtin_field", "REQUIRED_LANDMARKS"]

REQUIRED_LANDMARKS = ("red_outpost", "blue_outpost", "red_base", "blue_base")


@dataclass
class FieldModel:
    """A playing field. ``areas``: ``[{"name", "polygon" (K,2), "z", optional "plane": [a, b, c]}]``;
    ``structures``: ``[{"name", "center" [x, y, z_bottom], "size" [lx, ly, lz], "yaw" rad, "color"}]``."""

    name: str
    size: tuple[float, float]
    landmarks: dict[str, np.ndarray]
    outline: np.ndarray
    areas: list[dict] = field(default_factory=list)
    structures: list[dict] = field(default_factory=list)
    description: str = ""

    def __post_init__(self) -> None:
        self.size = (float(self.size[0]), float(self.size[1]))
        self.landmarks = {str(k): np.asarray(v, float).reshape(3) for k, v in self.landmarks.items()}
        self.outline = np.asarray(self.outline, float).reshape(-1, 2)
        areas = []
        for a in self.areas:
            a = dict(a)
            a["polygon"] = np.asarray(a["polygon"], float).reshape(-1, 2)
            a["z"] = float(a["z"])
            if a.get("plane") is not None:
                a["plane"] = [float(v) for v in a["plane"]]
            areas.append(a)
        self.areas = areas

    # --- serialisation ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        areas = []
        for a in self.areas:
            d = {"name": a["name"], "polygon": np.asarray(a["polygon"]).tolist(), "z": float(a["z"])}
            if a.get("plane") is not None:
                d["plane"] = list(a["plane"])
            for k, v in a.items():
                if k not in d and k != "plane":
                    d[k] = v
            areas.append(d)
        out = {
            "name": self.name,
            "size": list(self.size),
            "landmarks": {k: v.tolist() for k, v in self.landmarks.items()},
            "outline": self.outline.tolist(),
            "areas": areas,
        }
        if self.structures:
            out["structures"] = [_plain(s) for s in self.structures]
        if self.description:
            out["description"] = self.description
        return out

    @classmethod
    def from_dict(cls, d: dict, source: Any = None) -> "FieldModel":
        return field_from_dict(d, source)

    # --- geometry --------------------------------------------------------------------------------------------
    def area_heights(self, xy: np.ndarray) -> np.ndarray:
        """(N,2) -> (N, n_areas) top height of each area at xy, NaN where xy is outside that area."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        out = np.full((len(xy), len(self.areas)), np.nan)
        for j, a in enumerate(self.areas):
            inside = _points_in_polygon(xy, a["polygon"])
            out[inside, j] = _area_top(a, xy[inside])
        return out

    def surface_z(self, xy: np.ndarray) -> np.ndarray:
        """(N,2) -> (N,) height of the surface (highest raised area there, else the ground, 0)."""
        h = self.area_heights(xy)
        if h.shape[1] == 0:
            return np.zeros(len(h))
        with np.errstate(all="ignore"):
            top = np.nanmax(np.where(np.isnan(h), -np.inf, h), axis=1)
        return np.maximum(top, 0.0)

    def area_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,2) -> (N,) index of the area that forms the surface there (-1: ground)."""
        h = self.area_heights(xy)
        if h.shape[1] == 0:
            return np.full(len(h), -1)
        hh = np.where(np.isnan(h), -np.inf, h)
        idx = np.argmax(hh, axis=1)
        return np.where(np.isfinite(hh[np.arange(len(hh)), idx]), idx, -1)

    def intersect_rays(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Rays (N,3),(N,3) in the field frame -> (N,3) first hit with the surface solid; NaN rows where none."""
        t = self.ray_hits(origins, dirs)[0]
        o = np.asarray(origins, float).reshape(-1, 3)
        d = np.asarray(dirs, float).reshape(-1, 3)
        return o + t[:, None] * d

    def ray_hits(self, origins: np.ndarray, dirs: np.ndarray, t_min: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
        """First hit parameter ``t`` (N,) (NaN: none) and the id of what was hit (N,) (-1 ground, k area k's top or
        wall). ``origin + t * dir`` is the hit point; ``dir`` need not be unit length."""
        o = np.broadcast_to(np.asarray(origins, float).reshape(-1, 3), np.broadcast_shapes(np.shape(origins), np.shape(dirs))).reshape(-1, 3)
        d = np.broadcast_to(np.asarray(dirs, float).reshape(-1, 3), o.shape).reshape(-1, 3)
        n = len(o)
        best = np.full(n, np.inf)
        hit = np.full(n, -1, dtype=np.int64)
        with np.errstate(divide="ignore", invalid="ignore"):
            # ground z = 0
            tg = -o[:, 2] / d[:, 2]
            ok = (tg > t_min) & np.isfinite(tg)
            best = np.where(ok, tg, best)
            for j, a in enumerate(self.areas):
                poly = a["polygon"]
                # top: z = a x + b y + c  ->  (dz - a dx - b dy) t = a ox + b oy + c - oz
                pa, pb, pc = _plane_coeffs(a)
                den = d[:, 2] - pa * d[:, 0] - pb * d[:, 1]
                tt = (pa * o[:, 0] + pb * o[:, 1] + pc - o[:, 2]) / den
                cand = (tt > t_min) & (tt < best) & np.isfinite(tt)
                if np.any(cand):
                    idx = np.nonzero(cand)[0]
                    p = o[idx, :2] + tt[idx, None] * d[idx, :2]
                    inside = _points_in_polygon(p, poly)
                    idx = idx[inside]
                    best[idx] = tt[idx]
                    hit[idx] = j
                # walls: vertical faces along each edge, from z = 0 up to the top height on that edge
                q0 = poly
                q1 = np.roll(poly, -1, axis=0)
                e = q1 - q0  # (K,2)
                # solve o_xy + t d_xy = q0 + s e  (2x2 per ray x edge)
                det = d[:, None, 0] * (-e[None, :, 1]) - d[:, None, 1] * (-e[None, :, 0])
                rx = q0[None, :, 0] - o[:, None, 0]
                ry = q0[None, :, 1] - o[:, None, 1]
                tw = (rx * (-e[None, :, 1]) - ry * (-e[None, :, 0])) / det
                sw = (d[:, None, 0] * ry - d[:, None, 1] * rx) / det
                zw = o[:, None, 2] + tw * d[:, None, 2]
                xw = o[:, None, 0] + tw * d[:, None, 0]
                yw = o[:, None, 1] + tw * d[:, None, 1]
                ztop = pa * xw + pb * yw + pc
                okw = (tw > t_min) & (sw >= 0) & (sw <= 1) & (zw >= 0) & (zw <= ztop) & np.isfinite(tw)
                tw = np.where(okw, tw, np.inf).min(axis=1)
                better = tw < best
                best = np.where(better, tw, best)
                hit = np.where(better, j, hit)
        best = np.where(np.isfinite(best), best, np.nan)
        return best, hit

    def landmark_array(self, names: list[str]) -> np.ndarray:
        """(N,3) field coordinates of the named landmarks (KeyError for unknown names)."""
        return np.stack([self.landmarks[n] for n in names]) if names else np.zeros((0, 3))


# --- helpers ---------------------------------------------------------------------------------------------------


def _plane_coeffs(area: dict) -> tuple[float, float, float]:
    if area.get("plane") is not None:
        a, b, c = area["plane"]
        return float(a), float(b), float(c)
    return 0.0, 0.0, float(area["z"])


def _area_top(area: dict, xy: np.ndarray) -> np.ndarray:
    a, b, c = _plane_coeffs(area)
    return a * xy[:, 0] + b * xy[:, 1] + c


def _points_in_polygon(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule, vectorised over points and edges. (N,2), (K,2) -> (N,) bool."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) == 0:
        return np.zeros(0, bool)
    x, y = xy[:, 0:1], xy[:, 1:2]
    x0, y0 = poly[None, :, 0], poly[None, :, 1]
    p1 = np.roll(poly, -1, axis=0)
    x1, y1 = p1[None, :, 0], p1[None, :, 1]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return np.count_nonzero(crosses & (x < xint), axis=1) % 2 == 1


# --- built-in fields -------------------------------------------------------------------------------------------
def _mirror(p: tuple[float, ...], L: float = 28.0, W: float = 15.0) -> tuple[float, ...]:
    """Point symmetry about the field centre (the RMUC field is centrally symmetric: red <-> blue)."""
    return (L - p[0], W - p[1]) + tuple(p[2:])


def _mirror_name(name: str) -> str:
    """Name of the centrally mirrored landmark: red <-> blue and south (low y) <-> north (high y)."""
    swap = {"red": "blue", "blue": "red", "south": "north", "north": "south"}
    return "_".join(swap.get(part, part) for part in name.split("_"))


def _rmuc2024() -> FieldModel:
    L, W = 28.0, 15.0
    # Raised areas of the red half (blue = central mirror). See docs/field.md for the reasoning behind each number.
    red_trapezoid = [(5.5, 1.0), (10.5, 1.0), (9.5, 3.5), (5.5, 3.5)]
    central = [(12.0, 6.0), (13.0, 5.0), (15.0, 5.0), (16.0, 6.0), (16.0, 9.0), (15.0, 10.0), (13.0, 10.0), (12.0, 9.0)]
    red_ramp = [(10.4, 6.8), (12.0, 6.8), (12.0, 8.2), (10.4, 8.2)]
    H_CENTRAL, H_TRAP = 0.6, 0.4
    slope = H_CENTRAL / (12.0 - 10.4)  # 0.375: rises 0.6 m over 1.6 m (20.6 deg)
    areas = [
        {"name": "central_highland", "polygon": central, "z": H_CENTRAL},
        {"name": "red_ramp", "polygon": red_ramp, "z": H_CENTRAL / 2, "plane": [slope, 0.0, -slope * 10.4]},
        {"name": "blue_ramp", "polygon": [_mirror(p) for p in red_ramp], "z": H_CENTRAL / 2, "plane": [-slope, 0.0, slope * (L - 10.4)]},
        {"name": "red_trapezoid_highland", "polygon": red_trapezoid, "z": H_TRAP},
        {"name": "blue_trapezoid_highland", "polygon": [_mirror(p) for p in red_trapezoid], "z": H_TRAP},
    ]
    base_h, outpost_h = 1.1, 1.3
    red = {
        "red_base": (1.5, 7.5, base_h),
        "red_outpost": (11.0, 12.5, outpost_h),
        "red_highland_corner_a": (5.5, 3.5, H_TRAP),
        "red_highland_corner_b": (9.5, 3.5, H_TRAP),
        "red_ramp_foot_south": (10.4, 6.8, 0.0),
        "red_ramp_foot_north": (10.4, 8.2, 0.0),
        "central_highland_red_south": (12.0, 6.0, H_CENTRAL),
        "central_highland_red_north": (12.0, 9.0, H_CENTRAL),
    }
    landmarks: dict[str, tuple] = {}
    for k, v in red.items():
        landmarks[k] = v
        landmarks[_mirror_name(k)] = _mirror(v)
    landmarks.update({"corner_origin": (0.0, 0.0, 0.0), "corner_x": (L, 0.0, 0.0), "corner_xy": (L, W, 0.0), "corner_y": (0.0, W, 0.0)})
    structures = [
        {"name": "red_base", "center": [1.5, 7.5, 0.0], "size": [1.4, 1.4, base_h], "yaw": 0.0, "color": "red"},
        {"name": "blue_base", "center": [L - 1.5, W - 7.5, 0.0], "size": [1.4, 1.4, base_h], "yaw": 0.0, "color": "blue"},
        {"name": "red_outpost", "center": [11.0, 12.5, 0.0], "size": [0.6, 0.6, outpost_h], "yaw": 0.0, "color": "red"},
        {"name": "blue_outpost", "center": [L - 11.0, W - 12.5, 0.0], "size": [0.6, 0.6, outpost_h], "yaw": 0.0, "color": "blue"},
    ]
    return FieldModel(
        name="rmuc2024",
        size=(L, W),
        landmarks=landmarks,
        outline=[(0.0, 0.0), (L, 0.0), (L, W), (0.0, W)],
        areas=areas,
        structures=structures,
        description="RoboMaster University Championship-like field, 28 m x 15 m, centrally symmetric; see docs/field.md "
        "for which coordinates follow the rule manual's figures and which are approximations.",
    )


_BUILTIN = {"rmuc2024": _rmuc2024}
BUILTIN_FIELDS: tuple[str, ...] = tuple(_BUILTIN)


def builtin_field(name: str) -> FieldModel:
    if name not in _BUILTIN:
        raise InputError(name, f"unknown built-in field (built-in: {', '.join(BUILTIN_FIELDS)})")
    return _BUILTIN[name]()


# --- loading ---------------------------------------------------------------------------------------------------
def _num_list(value: Any, n: int | tuple[int, ...], where: str, src: Any) -> list[float]:
    ns = (n,) if isinstance(n, int) else n
    if not isinstance(value, (list, tuple)) or len(value) not in ns:
        raise InputError(src, f"{where}: expected a list of {' or '.join(map(str, ns))} numbers, got {value!r}")
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise InputError(src, f"{where}: expected numbers, got {value!r}") from None
    if not all(np.isfinite(out)):
        raise InputError(src, f"{where}: non-finite value")
    return out


def _polygon(value: Any, where: str, src: Any) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) < 3:
        raise InputError(src, f"{where}: expected a polygon of at least 3 [x, y] points")
    pts = np.array([_num_list(p, (2, 3), f"{where}[{i}]", src)[:2] for i, p in enumerate(value)])
    area2 = np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    if abs(area2) < 1e-9:
        raise InputError(src, f"{where}: polygon has zero area")
    return pts


def field_from_dict(d: Any, source: Any = None) -> FieldModel:
    """Validate a parsed field document (``name``, ``size``, ``landmarks``, optional ``outline``, ``areas``,
    ``structures``) and build a :class:`FieldModel`. Raises :class:`InputError` naming ``source`` and the key."""
    src = source
    if not isinstance(d, dict):
        raise InputError(src, "field file: top level must be a mapping with name, size, landmarks")
    name = d.get("name")
    if not isinstance(name, str) or not name:
        raise InputError(src, "name: expected a non-empty string")
    size = _num_list(d.get("size"), 2, "size", src)
    if size[0] <= 0 or size[1] <= 0:
        raise InputError(src, f"size: must be positive, got {size}")
    lms = d.get("landmarks")
    if not isinstance(lms, dict) or not lms:
        raise InputError(src, "landmarks: expected a mapping {name: [x, y, z]} with at least one landmark")
    landmarks = {str(k): np.array(_num_list(v, 3, f"landmarks.{k}", src)) for k, v in lms.items()}
    outline = _polygon(d["outline"], "outline", src) if d.get("outline") is not None else np.array([(0, 0), (size[0], 0), (size[0], size[1]), (0, size[1])], float)
    areas = []
    raw_areas = d.get("areas") or []
    if not isinstance(raw_areas, list):
        raise InputError(src, "areas: expected a list of {name, polygon, z}")
    for i, a in enumerate(raw_areas):
        where = f"areas[{i}]"
        if not isinstance(a, dict):
            raise InputError(src, f"{where}: expected a mapping with name, polygon, z")
        entry = dict(a)
        entry["name"] = str(a.get("name", f"area{i}"))
        entry["polygon"] = _polygon(a.get("polygon"), f"{where}.polygon", src)
        z = a.get("z")
        if a.get("plane") is not None:
            entry["plane"] = _num_list(a["plane"], 3, f"{where}.plane", src)
            if z is None:
                c = entry["polygon"].mean(axis=0)
                z = entry["plane"][0] * c[0] + entry["plane"][1] * c[1] + entry["plane"][2]
        if not isinstance(z, (int, float)) or isinstance(z, bool) or not np.isfinite(z):
            raise InputError(src, f"{where}.z: expected a number (height of the area's top, metres), got {z!r}")
        entry["z"] = float(z)
        areas.append(entry)
    structures = []
    for i, s in enumerate(d.get("structures") or []):
        where = f"structures[{i}]"
        if not isinstance(s, dict):
            raise InputError(src, f"{where}: expected a mapping with name, center, size")
        structures.append({
            **s,
            "name": str(s.get("name", f"structure{i}")),
            "center": _num_list(s.get("center"), 3, f"{where}.center", src),
            "size": _num_list(s.get("size"), 3, f"{where}.size", src),
            "yaw": float(s.get("yaw", 0.0)),
        })
    return FieldModel(name=name, size=tuple(size), landmarks=landmarks, outline=outline, areas=areas, structures=structures, description=str(d.get("description", "")))


def load_field(name_or_path: str | os.PathLike) -> FieldModel:
    """A built-in field by name (see :data:`BUILTIN_FIELDS`) or a YAML/JSON field file."""
    s = str(name_or_path)
    if s in _BUILTIN:
        return builtin_field(s)
    path = Path(s)
    if not path.exists():
        raise InputError(path, f"no such field file and not a built-in field (built-in: {', '.join(BUILTIN_FIELDS)})")
    if not path.is_file():
        raise InputError(path, "field model must be a YAML or JSON file")
    text = path.read_text(encoding="utf-8", errors="replace")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(text)
    except Exception as e:  # noqa: BLE001 - parser errors of either library -> one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else e.__class__.__name__
        raise InputError(path, f"cannot parse field file ({first})") from None
    return field_from_dict(data, path)

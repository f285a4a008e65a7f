"""Radar detection readers and the ``radarcal radar-lidar`` session folder.

Formats:

* **session CSV** (``radar.csv``): ``radar,x,y[,rcs,velocity]``, one row per detection, ``radar`` named as in
  ``rig.yaml``, x forward / y left in that radar's frame (metres), ``rcs`` dBsm, ``velocity`` m/s (radial or
  longitudinal, informative only). A header row is optional; ``#`` starts a comment line. Several frames may simply be
  concatenated (the calibration averages repeated detections).
* **ARS408 object CSV** (Continental ARS408 CAN object list as exported by OpenCalib):
  ``time_ns, track_id, velocity_x, velocity_y, position_x, position_y, dynprop, rcs, ...`` (26 columns). The
  published header is missing the comma between ``prob_of_exist`` and ``object_type`` (25 names, 26 values per row):
  the reader splits the fused name and says so in ``Ars408Objects.header_fixed``. Scans are numbered where
  ``track_id`` restarts at 0.
* **TU Delft multi_sensor_calibration example**: ``lidar.csv`` (3 rows x 4*M columns, four circle centres per board),
  ``radar.csv`` (2 x M), and the accumulator YAML (``/lidar_detector/lidar_pattern`` and
  ``/radar_detector/radar_pattern``, where the radar point's ``z`` holds the RCS).

Every reader raises :class:`radarcal.errors.InputError` naming the file (and the line) at fault.
"""

from __future__ import annotations

import csv
import io as _io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from radarcal import geometry
from radarcal.errors import InputError, read_text

__all__ = [
    "Ars408Objects",
    "RadarDetections",
    "RadarSessionInput",
    "RigConfig",
    "SessionScene",
    "is_ars408_csv",
    "read_ars408_csv",
    "read_opencalib_lidar2lidar",
    "read_radar_csv",
    "read_radar_session",
    "read_reflector_centres",
    "read_rig_yaml",
    "read_tudelft_accumulator",
    "read_tudelft_example",
    "read_tudelft_session",
]


@dataclass
class RadarDetections:
    radar: np.ndarray  # (N,) str: radar name per detection
    xy: np.ndarray  # (N,2) metres, radar frame
    rcs: np.ndarray  # (N,) dBsm (NaN when absent)
    velocity: np.ndarray  # (N,) m/s (NaN when absent)
    path: str = ""

    def of(self, name: str) -> np.ndarray:
        return self.xy[self.radar == name]

    def names(self) -> list[str]:
        return sorted(set(self.radar.tolist()))


def _num(tok: str, path, line: int, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(path, f"line {line}: {what} {tok.strip()!r} is not a number") from None
    if not np.isfinite(v):
        raise InputError(path, f"line {line}: {what} is not finite")
    return v


def read_radar_csv(path: str | os.PathLike) -> RadarDetections:
    """Read a session ``radar.csv`` (``radar,x,y[,rcs,velocity]``)."""
    path = Path(path)
    text = read_text(path, encoding="utf-8-sig")
    names, xy, rcs, vel = [], [], [], []
    for ln, row in enumerate(csv.reader(_io.StringIO(text)), start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        row = [c.strip() for c in row]
        if row[0].lower() == "radar" and len(row) > 1 and row[1].lower() == "x":
            continue  # header
        if len(row) < 3 or len(row) > 5:
            raise InputError(path, f"line {ln}: expected radar,x,y[,rcs,velocity] (3-5 fields), got {len(row)}")
        if not row[0]:
            raise InputError(path, f"line {ln}: empty radar name")
        names.append(row[0])
        xy.append((_num(row[1], path, ln, "x"), _num(row[2], path, ln, "y")))
        rcs.append(_num(row[3], path, ln, "rcs") if len(row) > 3 and row[3] != "" else np.nan)
        vel.append(_num(row[4], path, ln, "velocity") if len(row) > 4 and row[4] != "" else np.nan)
    return RadarDetections(np.array(names, dtype=str), np.array(xy, float).reshape(-1, 2), np.array(rcs, float), np.array(vel, float), str(path))


# --- ARS408 -------------------------------------------------------------------------------------------------------
_ARS408_FUSED = {"prob_of_existobject_type": ["prob_of_exist", "object_type"]}


@dataclass
class Ars408Objects:
    columns: dict  # name -> (N,) float array (every column of the file)
    xy: np.ndarray  # (N,2) position_x (forward), position_y (left)
    rcs: np.ndarray
    velocity: np.ndarray  # (N,2) velocity_x, velocity_y
    track_id: np.ndarray
    scan: np.ndarray  # (N,) scan index (track_id restarts at 0)
    header_fixed: str  # "" or what was repaired in the header
    path: str = ""

    def as_detections(self, radar: str) -> RadarDetections:
        return RadarDetections(np.full(len(self.xy), radar), self.xy, self.rcs, np.linalg.norm(self.velocity, axis=1), self.path)


def is_ars408_csv(path: str | os.PathLike) -> bool:
    try:
        with open(path, encoding="utf-8-sig") as f:
            head = f.readline().lower()
    except OSError:
        return False
    return "position_x" in head and "track_id" in head


def read_ars408_csv(path: str | os.PathLike) -> Ars408Objects:
    """Read an ARS408-style object list CSV; repairs the published header's missing comma (see module doc)."""
    path = Path(path)
    text = read_text(path, encoding="utf-8-sig")
    rows = list(csv.reader(_io.StringIO(text)))
    rows = [r for r in rows if r and "".join(r).strip()]
    if not rows:
        raise InputError(path, "empty file")
    header = [h.strip() for h in rows[0]]
    fixed = ""
    ncols = max(len(r) for r in rows[1:]) if len(rows) > 1 else len(header)
    if len(header) != ncols:
        repaired = []
        for h in header:
            repaired += _ARS408_FUSED.get(h, [h])
        if len(repaired) == ncols:
            fixed = "header had fused column name(s) " + ", ".join(repr(h) for h in header if h in _ARS408_FUSED) + " (missing comma): split"
            header = repaired
        else:
            raise InputError(path, f"line 1: header has {len(header)} names but rows have {ncols} values")
    need = ["track_id", "position_x", "position_y"]
    for k in need:
        if k not in header:
            raise InputError(path, f"line 1: no {k!r} column (not an ARS408 object list)")
    data = np.zeros((len(rows) - 1, len(header)))
    for i, r in enumerate(rows[1:]):  # per row: parse with line numbers for errors
        if len(r) != len(header):
            raise InputError(path, f"line {i + 2}: {len(r)} values, expected {len(header)}")
        for j, tok in enumerate(r):
            data[i, j] = _num(tok, path, i + 2, header[j])
    cols = {h: data[:, j] for j, h in enumerate(header)}
    tid = cols["track_id"].astype(int)
    scan = np.cumsum(np.r_[0, (np.diff(tid) < 0) | (tid[1:] == 0)]) if len(tid) else np.zeros(0, int)
    def g(k):
        return cols.get(k, np.full(len(tid), np.nan))
    return Ars408Objects(cols, np.stack([cols["position_x"], cols["position_y"]], axis=1), g("rcs"), np.stack([g("velocity_x"), g("velocity_y")], axis=1), tid, scan, fixed, str(path))


# --- TU Delft example ---------------------------------------------------------------------------------------------
def _read_matrix_csv(path: Path, rows: int) -> np.ndarray:
    text = read_text(path, encoding="utf-8-sig")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if len(lines) != rows:
        raise InputError(path, f"expected {rows} rows, got {len(lines)}")
    out = []
    for ln, line in enumerate(lines, start=1):
        out.append([_num(t, path, ln, "value") for t in line.split(",")])
    if len({len(r) for r in out}) != 1:
        raise InputError(path, "rows have different lengths")
    return np.array(out, float)


def read_tudelft_example(folder: str | os.PathLike, lidar_name: str = "lidar.csv", radar_name: str = "radar.csv") -> tuple[np.ndarray, np.ndarray]:
    """``(circles (M,4,3) LiDAR frame, radar_xy (M,2))`` from the TU Delft optimisation example CSVs."""
    folder = Path(folder)
    L = _read_matrix_csv(folder / lidar_name, 3)
    R = _read_matrix_csv(folder / radar_name, 2)
    if L.shape[1] % 4 or L.shape[1] // 4 != R.shape[1]:
        raise InputError(folder / lidar_name, f"{L.shape[1]} LiDAR columns do not make 4 circle centres per radar column ({R.shape[1]})")
    return L.T.reshape(-1, 4, 3), R.T.copy()


def read_tudelft_accumulator(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(circles (M,4,3), radar_xy (M,2), rcs (M,))`` from the accumulator YAML (radar ``z`` = RCS)."""
    path = Path(path)
    try:
        data = yaml.safe_load(read_text(path, encoding="utf-8-sig"))
    except yaml.YAMLError:
        raise InputError(path, "not valid YAML") from None
    try:
        lid = data["/lidar_detector/lidar_pattern"]
        rad = data["/radar_detector/radar_pattern"]
        circles = np.array([[[p["x"], p["y"], p["z"]] for p in m["points"]] for m in lid], float)
        radar = np.array([[m["points"][0]["x"], m["points"][0]["y"], m["points"][0]["z"]] for m in rad], float)
    except (KeyError, TypeError, IndexError, ValueError) as e:
        raise InputError(path, f"missing or bad field {e}") from None
    if circles.ndim != 3 or circles.shape[1:] != (4, 3) or len(circles) != len(radar):
        raise InputError(path, f"expected 4 LiDAR circle centres per location and one radar point each, got {circles.shape} / {radar.shape}")
    return circles, radar[:, :2], radar[:, 2]


# --- session folder -----------------------------------------------------------------------------------------------
@dataclass
class RigConfig:
    main_lidar: str
    lidars: list
    radars: list
    mount_heights: dict  # radar -> m above ground (None: estimate)
    init_T_main: dict  # sensor -> 4x4 T_main_sensor (initial guess) or absent
    reference_radar: str
    reflector_offset: float = 0.0
    head_size: float = 0.35
    reflector_edge: float | None = None  # trihedral edge (m) when known: plate fit and size checks
    range_gate: float = 4.0
    cluster_tol: float = 0.12
    ground_tol: float = 0.05
    forward: tuple = (0.0, 5.0)
    lateral: tuple = (-5.0, 5.0)
    T_vehicle_main: np.ndarray | None = None
    path: str = ""


def _pose(value, path, where) -> np.ndarray:
    """A 4x4 matrix or [x, y, z, roll, pitch, yaw] (deg)."""
    try:
        arr = np.asarray(value, float)
    except (TypeError, ValueError):
        raise InputError(path, f"{where}: expected [x, y, z, roll, pitch, yaw] (m, deg) or a 4x4 matrix") from None
    if arr.shape == (6,):
        return geometry.T_from_xyz_rpy_deg(*arr)
    if arr.shape == (4, 4) and geometry.is_rotation(arr[:3, :3], 1e-5):
        return arr
    raise InputError(path, f"{where}: expected [x, y, z, roll, pitch, yaw] (m, deg) or a 4x4 rigid matrix")


def read_rig_yaml(path: str | os.PathLike) -> RigConfig:
    path = Path(path)
    try:
        d = yaml.safe_load(read_text(path, encoding="utf-8-sig"))
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        raise InputError(path, f"not valid YAML{f' at line {mark.line + 1}' if mark else ''}") from None
    if not isinstance(d, dict):
        raise InputError(path, "expected a mapping with main_lidar, lidars, radars")
    lidars = d.get("lidars") or {}
    radars = d.get("radars") or {}
    if isinstance(lidars, list):
        lidars = {n: {} for n in lidars}
    if isinstance(radars, list):
        radars = {n: {} for n in radars}
    if not isinstance(lidars, dict) or not isinstance(radars, dict):
        raise InputError(path, "lidars / radars: expected mappings name -> settings")
    main = d.get("main_lidar") or (next(iter(lidars)) if lidars else None)
    if not main:
        raise InputError(path, "main_lidar: missing (and no lidars listed)")
    if main not in lidars:
        lidars = {main: {}, **lidars}
    if not radars and len(lidars) < 2:
        raise InputError(path, "radars: none listed (and fewer than two LiDARs: nothing to calibrate)")
    init, heights = {}, {}
    for n, s in {**lidars, **radars}.items():
        s = s or {}
        if not isinstance(s, dict):
            raise InputError(path, f"{n}: expected a mapping")
        if s.get("initial_T_main") is not None:
            init[n] = _pose(s["initial_T_main"], path, f"{n}.initial_T_main")
    for n, s in radars.items():
        h = (s or {}).get("mount_height_m")
        if h is not None and not isinstance(h, (int, float)):
            raise InputError(path, f"radars.{n}.mount_height_m: expected a number, got {h!r}")
        heights[n] = None if h is None else float(h)
    ref = d.get("reference_radar") or ("radar_middle" if "radar_middle" in radars else (list(radars)[len(radars) // 2] if radars else ""))
    if radars and ref not in radars:
        raise InputError(path, f"reference_radar {ref!r} is not one of the radars ({', '.join(radars)})")
    refl = d.get("reflector") or {}
    ext = d.get("extraction") or {}
    reg = d.get("filter_region") or {}

    def f(m, k, default):
        v = m.get(k, default)
        if not isinstance(v, (int, float)):
            raise InputError(path, f"{k}: expected a number, got {v!r}")
        return float(v)

    def rng2(k, default):
        v = reg.get(k, default)
        if not (isinstance(v, (list, tuple)) and len(v) == 2):
            raise InputError(path, f"filter_region.{k}: expected [min, max]")
        return (float(v[0]), float(v[1]))

    Tvm = _pose(d["T_vehicle_main"], path, "T_vehicle_main") if d.get("T_vehicle_main") is not None else None
    edge = f(refl, "edge_m", 0.0) or None
    return RigConfig(main, list(lidars), list(radars), heights, init, ref, f(refl, "offset_m", 0.0), f(refl, "head_size_m", 0.35), edge, f(ext, "range_gate_m", 4.0),
                     f(ext, "cluster_tol_m", 0.12), f(ext, "ground_tol_m", 0.05), rng2("forward_m", [0.0, 5.0]), rng2("lateral_m", [-5.0, 5.0]), Tvm, str(path))


@dataclass
class SessionScene:
    """One reflector placement. ``clouds``: LiDAR name -> file (read by :meth:`cloud`, the one place clouds are read
    here); ``centres``: LiDAR name -> (K,3) reflector centres given directly (TU Delft style; no cloud needed)."""

    name: str
    clouds: dict  # lidar -> Path
    detections: RadarDetections
    notes: list = field(default_factory=list)
    centres: dict = field(default_factory=dict)  # lidar -> (K,3) reflector centres in that LiDAR's frame (m)
    boards: dict = field(default_factory=dict)  # lidar -> ((M,K,3) board circle centres, reflector offset behind the board (m))

    cloud_topic: str | None = None  # bag topic of the clouds when a scene's cloud is a ROS bag with several

    def cloud(self, lidar: str):
        """The :class:`radarcal.io.clouds.Cloud` of ``lidar`` in this scene, read by
        :func:`radarcal.io.cloud_sources.read_scene_cloud` (a cloud file, or a bag's clouds on ``cloud_topic`` merged);
        ``InputError`` when missing or empty."""
        from radarcal.io.cloud_sources import read_scene_cloud

        if lidar not in self.clouds:
            raise InputError(self.name, f"no cloud for LiDAR {lidar!r} in this scene")
        c = read_scene_cloud(self.clouds[lidar], self.cloud_topic)
        if len(c) == 0:
            raise InputError(self.clouds[lidar], "empty point cloud")
        return c


@dataclass
class RadarSessionInput:
    root: Path
    rig: RigConfig
    scenes: list  # [SessionScene]
    kind: str = "session"  # "session" (rig.yaml folder) | "tudelft" (board centres + radar CSVs) | "opencalib_lidar2lidar"

    def input_files(self) -> list[Path]:
        out = [Path(self.rig.path)] if self.rig.path else []
        for s in self.scenes:
            for c in s.clouds.values():  # a ROS2 bag is a folder: its files
                out += sorted(f for f in Path(c).iterdir() if f.is_file()) if Path(c).is_dir() else [Path(c)]
            if s.detections.path:
                out += [Path(p) for p in s.detections.path.split(os.pathsep)]
        return [p for p in dict.fromkeys(out) if p.is_file()]


def _empty_detections() -> RadarDetections:
    return RadarDetections(np.zeros(0, dtype=str), np.zeros((0, 2)), np.zeros(0), np.zeros(0), "")


def read_reflector_centres(path: str | os.PathLike) -> dict:
    """``reflectors.csv``: ``lidar,x,y,z`` rows (reflector centres in that LiDAR's frame, m; header optional)."""
    path = Path(path)
    text = read_text(path, encoding="utf-8-sig")
    out: dict = {}
    for ln, row in enumerate(csv.reader(_io.StringIO(text)), start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        row = [c.strip() for c in row]
        if row[0].lower() == "lidar":
            continue
        if len(row) != 4:
            raise InputError(path, f"line {ln}: expected lidar,x,y,z (4 fields), got {len(row)}")
        out.setdefault(row[0], []).append([_num(v, path, ln, k) for v, k in zip(row[1:], "xyz")])
    return {k: np.array(v, float) for k, v in out.items()}


def read_tudelft_session(folder: Path, board_offset: float = 0.105) -> RadarSessionInput:
    """The TU Delft example folder as shipped (``lidar.csv`` 3 x 4M board circle centres, ``radar.csv`` 2 x M): one
    LiDAR ``lidar``, one radar ``radar`` (height unknown: estimated), reflector = board centre moved 0.105 m behind the
    board; all M placements in one scene (each board is one reflector)."""
    circles, rxy = read_tudelft_example(folder)
    rig = RigConfig("lidar", ["lidar"], ["radar"], {"radar": None}, {}, "radar", path=str(folder / "lidar.csv"))
    det = RadarDetections(np.full(len(rxy), "radar"), rxy, np.full(len(rxy), np.nan), np.full(len(rxy), np.nan), str(folder / "radar.csv"))
    note = f"TU Delft example: {len(rxy)} board placements, reflector {board_offset:g} m behind each board's circle centres"
    return RadarSessionInput(folder, rig, [SessionScene("boards", {}, det, [note], boards={"lidar": (circles, board_offset)})], "tudelft")


def read_opencalib_lidar2lidar(folder: Path) -> RadarSessionInput:
    """OpenCalib's ``lidar2lidar`` sample as shipped: ``initial_extrinsic.txt`` ((Roll,Pitch,Yaw,tx,ty,tz) per device,
    degrees and metres, child -> device 0) and ``lidar_cloud_path.txt`` (device id -> cloud file); device 0 is the main
    LiDAR. Sensor names are the cloud file stems."""
    init_path, paths_path = folder / "initial_extrinsic.txt", folder / "lidar_cloud_path.txt"
    guesses, dev = {}, None
    for ln, line in enumerate(read_text(init_path).splitlines(), start=1):
        if line.startswith("device_id"):
            try:
                dev = int(line.split(":")[1])
            except (IndexError, ValueError):
                raise InputError(init_path, f"line {ln}: bad device_id") from None
        elif line.startswith("(Roll") and dev is not None:
            vals = line.split(":", 1)[1].split()
            if len(vals) != 6:
                raise InputError(init_path, f"line {ln}: expected 6 numbers (roll pitch yaw tx ty tz)")
            roll, pitch, yaw, tx, ty, tz = (_num(v, init_path, ln, "value") for v in vals)
            guesses[dev] = geometry.T_from_xyz_rpy_deg(tx, ty, tz, roll, pitch, yaw)
    files, dev = {}, None
    for ln, line in enumerate(read_text(paths_path).splitlines(), start=1):  # "device_id: N" then "path: <file>"
        key, _, val = line.partition(":")
        if key.strip() == "device_id":
            try:
                dev = int(val)
            except ValueError:
                raise InputError(paths_path, f"line {ln}: bad device_id") from None
        elif key.strip() == "path" and dev is not None:
            files[dev] = folder / Path(val.strip()).name
    if 0 not in files or len(files) < 2:
        raise InputError(paths_path, "expected device ids 0 (main) and at least one more with their cloud files")
    names = {d: p.stem for d, p in files.items()}
    main = names[0]
    init = {names[d]: T for d, T in guesses.items() if d in names and d != 0}
    rig = RigConfig(main, [names[d] for d in sorted(files)], [], {}, init, "", path=str(init_path))
    sc = SessionScene("0", {names[d]: p for d, p in files.items()}, _empty_detections(), [f"OpenCalib lidar2lidar sample: main LiDAR {main} (device 0)"])
    return RadarSessionInput(folder, rig, [sc], "opencalib_lidar2lidar")


def _lidar_cloud_file(scene: Path, lidar: str) -> Path | None:
    """The cloud of ``lidar`` in a scene folder: ``<lidar>.pcd|.ply|.bin|.npy``, a ROS1/ROS2 bag ``<lidar>.bag|.mcap|.db3``
    or a ROS2 bag folder ``<lidar>/`` (with ``metadata.yaml``); None when there is none."""
    from radarcal.io.cloud_sources import BAG_SUFFIXES
    from radarcal.io.clouds import CLOUD_SUFFIXES

    for suf in (*CLOUD_SUFFIXES, *BAG_SUFFIXES):
        if (scene / f"{lidar}{suf}").is_file():
            return scene / f"{lidar}{suf}"
    return scene / lidar if (scene / lidar / "metadata.yaml").is_file() else None


def read_radar_session(folder: str | os.PathLike, cloud_topic: str | None = None) -> RadarSessionInput:
    """A session folder: ``rig.yaml`` + ``scenes/<k>/{<lidar>.pcd | <lidar>.bag | reflectors.csv, radar.csv |
    <radar>.csv}`` (a LiDAR's cloud may be a ROS1/ROS2 bag, its clouds on ``cloud_topic`` merged, see
    :func:`_lidar_cloud_file`; a scene may hold ARS408 object lists ``<radar>.csv`` instead of ``radar.csv``, reflector
    centres ``reflectors.csv`` instead of the main LiDAR's cloud, and no radar file at all in a LiDAR-only rig); or,
    recognised by their files, the TU Delft example folder (``lidar.csv`` + ``radar.csv``) and OpenCalib's lidar2lidar
    sample (``initial_extrinsic.txt``)."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(root, "session folder not found")
    if not (root / "rig.yaml").is_file():
        if (root / "lidar.csv").is_file() and (root / "radar.csv").is_file():
            return read_tudelft_session(root)
        if (root / "initial_extrinsic.txt").is_file():
            return read_opencalib_lidar2lidar(root)
    rig = read_rig_yaml(root / "rig.yaml")
    sdir = root / "scenes"
    if not sdir.is_dir():
        raise InputError(sdir, "no scenes/ folder (one sub-folder per reflector placement)")
    scenes = []
    for d in sorted(p for p in sdir.iterdir() if p.is_dir()):
        clouds = {lid: f for lid in rig.lidars if (f := _lidar_cloud_file(d, lid)) is not None}
        centres = read_reflector_centres(d / "reflectors.csv") if (d / "reflectors.csv").is_file() else {}
        unknown = sorted(set(centres) - set(rig.lidars))
        if unknown:
            raise InputError(d / "reflectors.csv", f"LiDAR name(s) {', '.join(unknown)} not in rig.yaml ({', '.join(rig.lidars)})")
        if rig.main_lidar not in clouds and rig.main_lidar not in centres:
            raise InputError(d, f"no cloud for the main LiDAR {rig.main_lidar!r} ({rig.main_lidar}.pcd) and no reflectors.csv")
        for lid in rig.lidars:
            if lid != rig.main_lidar and lid not in clouds and lid not in centres and any(_lidar_cloud_file(e, lid) for e in sdir.iterdir() if e.is_dir()):
                raise InputError(d / f"{lid}.pcd", f"cloud of LiDAR {lid!r} missing in this scene (other scenes have one)")
        notes = []
        if (d / "radar.csv").is_file():
            det = read_radar_csv(d / "radar.csv")
            unknown = sorted(set(det.radar.tolist()) - set(rig.radars))
            if unknown:
                raise InputError(d / "radar.csv", f"radar name(s) {', '.join(unknown)} not in rig.yaml ({', '.join(rig.radars)})")
        else:
            parts = []
            for r in rig.radars:
                p = d / f"{r}.csv"
                if p.is_file():
                    if not is_ars408_csv(p):
                        raise InputError(p, "per-radar CSV must be an ARS408 object list (use radar.csv for radar,x,y rows)")
                    obj = read_ars408_csv(p)
                    if obj.header_fixed:
                        notes.append(f"{p.name}: {obj.header_fixed}")
                    parts.append(obj.as_detections(r))
            if not parts and rig.radars:
                raise InputError(d, "no radar.csv (radar,x,y[,rcs,velocity]) and no <radar>.csv ARS408 lists")
            det = RadarDetections(np.concatenate([p.radar for p in parts]), np.concatenate([p.xy for p in parts]), np.concatenate([p.rcs for p in parts]),
                                  np.concatenate([p.velocity for p in parts]), os.pathsep.join(p.path for p in parts)) if parts else _empty_detections()
        scenes.append(SessionScene(d.name, clouds, det, notes, centres, cloud_topic=cloud_topic))
    if not scenes:
        raise InputError(sdir, "no scene folders")
    return RadarSessionInput(root, rig, scenes)

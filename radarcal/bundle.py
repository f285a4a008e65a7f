"""The calibration bundle: one versioned YAML file, the single source of truth every command writes and the
runtime reads.

Why YAML: a person can read and ``git diff`` it (one matrix row per line), comments survive in hand edits, and
JSON is a subset, so a bundle written by another tool as JSON loads too. Floats are written with ``repr`` so a
save/load round trip is exact.

Layout (schema_version 1)::

    schema_version: 1
    radarcal_version: 0.1.0
    cameras:    {cam0: {model, image_size, K, dist, rms_px, sigma, provenance}}
    sensors:    {lidar0: {type: lidar|radar|camera, ...mounting metadata}}
    transforms: {T_cam0_lidar0: {target: cam0, source: lidar0, T: 4x4, method, residual, sigma, provenance}}
    field:      null | {name, size, landmarks, ...}
    runtime:    {hero_range_offset_m, cloud_queue_points, cloud_queue_age_s, ...}
    sessions:   {"intrinsics/cam0": relative path of a session file (observations for reports)}

Saving is atomic (temp file + fsync + rename) and keeps the previous file as a timestamped backup.
"""

from __future__ import annotations

import copy
import datetime as _dt
import hashlib
import io as _io
import os
import shutil
import tempfile
from glob import escape as glob_escape
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import yaml

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.errors import InputError, read_text
from radarcal.plain import to_plain as _plain

__all__ = [
    "SCHEMA_VERSION",
    "Provenance",
    "CameraEntry",
    "TransformEntry",
    "Bundle",
    "load_bundle",
    "load_or_create_bundle",
    "save_bundle",
    "save_session",
    "load_session",
    "read_session_file",
    "hash_inputs",
    "DEFAULT_RUNTIME",
    "BACKUPS_KEPT",
]

BACKUPS_KEPT = 10  # timestamped backups kept next to a bundle; older ones are removed on save

SCHEMA_VERSION = 1

def _default_runtime() -> dict[str, Any]:
    from radarcal.runtime.config import RunConfig  # the one declaration of the runtime defaults (no numpy: light)

    return RunConfig.bundle_defaults()


DEFAULT_RUNTIME: dict[str, Any] = _default_runtime()  # what a new bundle's runtime: section lists


def _version() -> str:
    from radarcal import __version__

    return __version__


def hash_inputs(paths: Iterable[str | os.PathLike] = (), extra: Any = None) -> str:
    """sha256 over the bytes of the input files (in the given order) and a repr of ``extra`` (options)."""
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        h.update(p.name.encode())
        if p.is_file():
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
    if extra is not None:
        h.update(repr(extra).encode())
    return h.hexdigest()


@dataclass
class Provenance:
    """Who wrote an entry: the command line, when, which radarcal, and a hash of its inputs."""

    command: str
    time: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    radarcal_version: str = field(default_factory=_version)
    inputs_sha256: str = ""

    def to_dict(self) -> dict:
        return {"command": self.command, "time": self.time, "radarcal_version": self.radarcal_version, "inputs_sha256": self.inputs_sha256}

    @classmethod
    def from_dict(cls, d: dict | None) -> "Provenance":
        d = d or {}
        return cls(command=str(d.get("command", "")), time=str(d.get("time", "")), radarcal_version=str(d.get("radarcal_version", "")), inputs_sha256=str(d.get("inputs_sha256", "")))


@dataclass
class CameraEntry:
    camera: Camera
    rms_px: float | None = None
    sigma: dict[str, float] = field(default_factory=dict)
    provenance: Provenance = field(default_factory=lambda: Provenance(command=""))
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = self.camera.to_dict()
        d.update({"rms_px": self.rms_px, "sigma": dict(self.sigma), "provenance": self.provenance.to_dict()})
        if self.extra:
            d["extra"] = self.extra
        return d


@dataclass
class TransformEntry:
    """``T`` maps points in ``source`` into ``target`` (``T_target_source``)."""

    target: str
    source: str
    T: np.ndarray
    method: str = ""
    residual: dict[str, Any] = field(default_factory=dict)
    sigma: dict[str, float] = field(default_factory=dict)
    provenance: Provenance = field(default_factory=lambda: Provenance(command=""))

    @property
    def name(self) -> str:
        return f"T_{self.target}_{self.source}"

    def to_dict(self) -> dict:
        return {
            "target": self.target,
            "source": self.source,
            "T": np.asarray(self.T, float).tolist(),
            "method": self.method,
            "residual": _plain(self.residual),
            "sigma": _plain(self.sigma),
            "provenance": self.provenance.to_dict(),
        }


@dataclass
class Bundle:
    """In-memory bundle. Mutate with the ``set_*`` methods, then :func:`save_bundle`."""

    cameras: dict[str, CameraEntry] = field(default_factory=dict)
    sensors: dict[str, dict[str, Any]] = field(default_factory=dict)
    transforms: dict[str, TransformEntry] = field(default_factory=dict)
    field_model: dict[str, Any] | None = None
    runtime: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_RUNTIME))
    sessions: dict[str, str] = field(default_factory=dict)
    path: Path | None = None
    _field_cache: tuple[int, Any] | None = field(default=None, init=False, repr=False, compare=False)

    # --- queries ---------------------------------------------------------------------------------------------
    def field(self):
        """The field model as a :class:`radarcal.field.FieldModel`, parsed once (``radarcal.field.field_from_dict``;
        an ``InputError`` naming the bundle when it is invalid); None when the bundle has none. Assigning a new
        ``field_model`` dict re-parses (the cache follows the dict object, not edits inside it)."""
        if not self.field_model:
            return None
        if self._field_cache is None or self._field_cache[0] != id(self.field_model):
            from radarcal.field import field_from_dict

            self._field_cache = (id(self.field_model), field_from_dict(self.field_model, f"{self.path}: field" if self.path else "bundle field"))
        return self._field_cache[1]

    def camera(self, name: str) -> Camera:
        if name not in self.cameras:
            known = ", ".join(sorted(self.cameras)) or "none"
            raise InputError(self.path, f"no camera {name!r} in the bundle (cameras: {known})")
        return self.cameras[name].camera

    def resolve_camera(self, name: str | None, option: str = "--camera") -> str:
        """The camera a per-camera command works on: ``name`` (checked), else the bundle's only camera; several
        cameras and no name -> an ``InputError`` naming ``option`` and the choices."""
        if name is not None:
            self.camera(name)
            return name
        if len(self.cameras) == 1:
            return next(iter(self.cameras))
        if not self.cameras:
            raise InputError(self.path, "no camera in the bundle (run `radarcal intrinsics` or `radarcal bundle import` first)")
        raise InputError(option, f"the bundle has {len(self.cameras)} cameras ({', '.join(sorted(self.cameras))}): pick one with {option}")

    def frames(self) -> set[str]:
        out = set(self.cameras) | set(self.sensors)
        for e in self.transforms.values():
            out |= {e.target, e.source}
        return out

    def T(self, target: str, source: str) -> np.ndarray:
        """``T_target_source`` (4x4), chaining and inverting stored transforms along the shortest path."""
        if target == source:
            return np.eye(4)
        graph: dict[str, list[tuple[str, np.ndarray]]] = {}
        for e in self.transforms.values():
            graph.setdefault(e.target, []).append((e.source, np.asarray(e.T, float)))  # T_target_source: target<-source
            graph.setdefault(e.source, []).append((e.target, geometry.invert_T(e.T)))
        # BFS from target, accumulating T_target_node
        seen = {target: np.eye(4)}
        queue = deque([target])
        while queue:
            node = queue.popleft()
            for nxt, T_node_nxt in graph.get(node, []):
                if nxt not in seen:
                    seen[nxt] = seen[node] @ T_node_nxt
                    if nxt == source:
                        return seen[nxt]
                    queue.append(nxt)
        reach = ", ".join(sorted(set(seen) - {target})) or "nothing"
        stored = ", ".join(sorted(self.transforms)) or "none"
        raise InputError(self.path, f"no transform chain from {source!r} to {target!r}: {target!r} connects to {reach}; stored transforms: {stored}")

    def has_T(self, target: str, source: str) -> bool:
        try:
            self.T(target, source)
            return True
        except InputError:
            return False

    # --- updates ---------------------------------------------------------------------------------------------
    def set_camera(self, name: str, camera: Camera, rms_px: float | None = None, sigma: dict | None = None, provenance: Provenance | None = None, extra: dict | None = None) -> None:
        self.cameras[name] = CameraEntry(camera, None if rms_px is None else float(rms_px), dict(sigma or {}), provenance or Provenance(command=""), dict(extra or {}))
        self.sensors.setdefault(name, {"type": "camera"})

    def set_transform(self, target: str, source: str, T: np.ndarray, method: str = "", residual: dict | None = None, sigma: dict | None = None, provenance: Provenance | None = None) -> TransformEntry:
        """Store ``T_target_source``. An entry for the reverse direction is replaced (one edge per frame pair)."""
        if not target or not source or target == source:
            raise InputError(self.path, f"transforms.T_{target}_{source}: needs two different, non-empty frame names")
        T = np.asarray(T, float)
        _check_T(T, f"transforms.T_{target}_{source}.T", self.path)
        self.transforms.pop(f"T_{source}_{target}", None)
        entry = TransformEntry(target, source, T, method, dict(residual or {}), dict(sigma or {}), provenance or Provenance(command=""))
        self.transforms[entry.name] = entry
        return entry

    def set_sensor(self, name: str, **meta: Any) -> None:
        self.sensors.setdefault(name, {}).update(meta)

    # --- serialisation ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "schema_version": SCHEMA_VERSION,
            "radarcal_version": _version(),
            "cameras": {k: v.to_dict() for k, v in self.cameras.items()},
            "sensors": _plain(self.sensors),
            "transforms": {k: v.to_dict() for k, v in self.transforms.items()},
            "field": _plain(self.field_model),
            "runtime": _plain(self.runtime),
            "sessions": dict(self.sessions),
        }

    def dumps(self) -> str:
        return "# radarcal calibration bundle (T_a_b maps points in frame b into frame a; metres, radians)\n" + yaml.safe_dump(
            self.to_dict(), sort_keys=False, default_flow_style=None, width=200, allow_unicode=True
        )




# --- validation --------------------------------------------------------------------------------------------------
def _matrix(value: Any, shape: tuple[int, ...], where: str, path: Any) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(path, f"{where}: expected a {'x'.join(map(str, shape))} matrix of numbers") from None
    if arr.shape != shape:
        got = "x".join(map(str, arr.shape)) or "a scalar"
        raise InputError(path, f"{where}: expected {'x'.join(map(str, shape))}, got {got}")
    if not np.all(np.isfinite(arr)):
        raise InputError(path, f"{where}: non-finite value")
    return arr


def _vector(value: Any, where: str, path: Any) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(path, f"{where}: expected a list of numbers, got {value!r}"[:200]) from None
    if not np.all(np.isfinite(arr)):
        raise InputError(path, f"{where}: non-finite value")
    return arr


def _check_T(T: np.ndarray, where: str, path: Any) -> np.ndarray:
    T = _matrix(T, (4, 4), where, path)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise InputError(path, f"{where}: last row must be [0, 0, 0, 1]")
    if not geometry.is_rotation(T[:3, :3], tol=1e-5):
        raise InputError(path, f"{where}: rotation part is not orthonormal with det +1")
    return T


def _require_mapping(value: Any, where: str, path: Any) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise InputError(path, f"{where}: expected a mapping, got {type(value).__name__}")
    return value


def bundle_from_dict(data: Any, path: Any = None) -> Bundle:
    """Validate a parsed bundle document (any known schema version) and build a :class:`Bundle`."""
    if not isinstance(data, dict):
        raise InputError(path, "not a radarcal bundle (top level is not a mapping)")
    data = migrate(data, path)
    b = Bundle(path=Path(path) if path else None)
    for name, d in _require_mapping(data.get("cameras"), "cameras", path).items():
        where = f"cameras.{name}"
        d = _require_mapping(d, where, path)
        K = _matrix(d.get("K"), (3, 3), f"{where}.K", path)
        dist = _vector(d.get("dist"), f"{where}.dist", path) if d.get("dist") is not None else np.zeros(5)
        size = d.get("image_size")
        if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
            raise InputError(path, f"{where}.image_size: expected [width, height] (positive integers), got {size!r}")
        try:
            cam = Camera(tuple(size), K, dist, str(d.get("model", "pinhole")))
        except ValueError as e:
            raise InputError(path, f"{where}.{e}") from None
        rms = d.get("rms_px")
        if rms is not None and not (isinstance(rms, (int, float)) and not isinstance(rms, bool) and np.isfinite(rms) and rms >= 0):
            raise InputError(path, f"{where}.rms_px: expected a non-negative number, got {rms!r}")
        sigma = _require_mapping(d.get("sigma"), f"{where}.sigma", path)
        extra = _require_mapping(d.get("extra"), f"{where}.extra", path)
        prov = Provenance.from_dict(_require_mapping(d.get("provenance"), f"{where}.provenance", path))
        b.cameras[str(name)] = CameraEntry(cam, None if rms is None else float(rms), dict(sigma), prov, dict(extra))
    b.sensors = {str(k): dict(_require_mapping(v, f"sensors.{k}", path)) for k, v in _require_mapping(data.get("sensors"), "sensors", path).items()}
    for name, d in _require_mapping(data.get("transforms"), "transforms", path).items():
        where = f"transforms.{name}"
        d = _require_mapping(d, where, path)
        target, source = d.get("target"), d.get("source")
        if not target or not source:
            raise InputError(path, f"{where}: needs 'target' and 'source' frame names")
        if target == source:
            raise InputError(path, f"{where}: target and source are the same frame")
        if name != f"T_{target}_{source}":
            raise InputError(path, f"{where}: key does not match target/source (expected T_{target}_{source})")
        T = _check_T(d.get("T"), f"{where}.T", path)
        residual = _require_mapping(d.get("residual"), f"{where}.residual", path)
        sigma = _require_mapping(d.get("sigma"), f"{where}.sigma", path)
        prov = Provenance.from_dict(_require_mapping(d.get("provenance"), f"{where}.provenance", path))
        b.transforms[str(name)] = TransformEntry(str(target), str(source), T, str(d.get("method") or ""), dict(residual), dict(sigma), prov)
    fm = data.get("field")
    b.field_model = dict(_require_mapping(fm, "field", path)) if fm is not None else None
    b.runtime = {**DEFAULT_RUNTIME, **_require_mapping(data.get("runtime"), "runtime", path)}
    off = b.runtime.get("hero_range_offset_m")
    if not (isinstance(off, (int, float)) and not isinstance(off, bool) and np.isfinite(off)):
        raise InputError(path, f"runtime.hero_range_offset_m: expected a finite number, got {off!r}")
    b.sessions = {str(k): str(v) for k, v in _require_mapping(data.get("sessions"), "sessions", path).items()}
    return b


# --- migrations --------------------------------------------------------------------------------------------------
def _migrate_v0_to_v1(d: dict) -> dict:
    """v0 (the prototype scripts' format): ``version: 0``; cameras as flat ``fx fy cx cy dist width height``;
    ``extrinsics: {"lidar0->cam0": 4x4}`` where ``"a->b"`` maps points in a into b; ``hero_offset`` at top level."""
    out: dict[str, Any] = {"schema_version": 1, "cameras": {}, "sensors": {}, "transforms": {}, "field": d.get("field"), "runtime": {}, "sessions": {}}
    for name, c in (d.get("cameras") or {}).items():
        K = [[c["fx"], 0.0, c["cx"]], [0.0, c["fy"], c["cy"]], [0.0, 0.0, 1.0]]
        out["cameras"][name] = {
            "model": c.get("model", "pinhole"),
            "image_size": [c["width"], c["height"]],
            "K": K,
            "dist": list(c.get("dist", [0, 0, 0, 0, 0])),
            "rms_px": c.get("rms"),
            "sigma": {},
            "provenance": {"command": "migrated from schema v0"},
        }
    for key, T in (d.get("extrinsics") or {}).items():
        source, target = [s.strip() for s in key.split("->")]
        out["transforms"][f"T_{target}_{source}"] = {"target": target, "source": source, "T": T, "method": "migrated from schema v0", "provenance": {"command": "migrated from schema v0"}}
    if "hero_offset" in d:
        out["runtime"]["hero_range_offset_m"] = d["hero_offset"]
    return out


_MIGRATIONS = {0: _migrate_v0_to_v1}


def migrate(data: dict, path: Any = None) -> dict:
    """Bring a parsed bundle of any older schema version up to :data:`SCHEMA_VERSION`."""
    version = data.get("schema_version", data.get("version"))
    if not isinstance(version, int):
        raise InputError(path, f"schema_version: expected an integer, got {version!r}")
    if version > SCHEMA_VERSION:
        raise InputError(path, f"schema_version {version} is newer than this radarcal understands ({SCHEMA_VERSION}); upgrade radarcal")
    data = copy.deepcopy(data)
    while version < SCHEMA_VERSION:
        try:
            data = _MIGRATIONS[version](data)
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise InputError(path, f"cannot migrate schema v{version}: missing or bad field {e}") from None
        version = data["schema_version"]
    return data


# --- files -------------------------------------------------------------------------------------------------------
def load_bundle(path: str | os.PathLike) -> Bundle:
    """Read, migrate and validate a bundle. Raises :class:`InputError` naming the file and the field."""
    path = Path(path)
    text = read_text(path, "bundle")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        raise InputError(path, f"not valid YAML/JSON{where}") from None
    return bundle_from_dict(data, path)


def load_or_create_bundle(path: str | os.PathLike) -> Bundle:
    """Load ``path`` if it exists, else an empty bundle that will be saved there."""
    path = Path(path)
    if path.exists():
        return load_bundle(path)
    return Bundle(path=path)


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    """The process umask (read without changing it where /proc allows; else set and restored at once)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _target_mode(path: Path) -> int:
    """Permission bits for a file written at ``path``: the existing file's, else what ``open()`` gives a new file."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return 0o666 & ~_umask()


def _atomic_write(path: Path, data: bytes, keep_backup: bool = True) -> Path | None:
    """Write ``data`` to ``path`` atomically; the previous file (if any) is kept as ``<name>.<UTC time>.bak``.
    The file keeps its permission bits (a new one follows the umask, as ``open()`` would create it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = _target_mode(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    backup = None
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if keep_backup and path.exists():
            stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%S%fZ")
            backup = path.with_name(f"{path.name}.{stamp}.bak")
            shutil.copy2(path, backup)
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    if backup is not None:
        _prune_backups(path)
    return backup


def _prune_backups(path: Path, keep: int | None = None) -> None:
    """Remove all but the newest ``keep`` (default :data:`BACKUPS_KEPT`) timestamped backups of ``path``."""
    keep = BACKUPS_KEPT if keep is None else keep
    baks = sorted(path.parent.glob(f"{glob_escape(path.name)}.*.bak"))  # the UTC stamp sorts by time
    for old in baks[: max(len(baks) - keep, 0)]:
        try:
            old.unlink()
        except OSError:
            pass


def save_bundle(bundle: Bundle, path: str | os.PathLike | None = None) -> Path:
    """Validate and atomically write the bundle (previous file kept as a timestamped ``.bak``). Returns the path."""
    path = Path(path) if path is not None else bundle.path
    if path is None:
        raise ValueError("save_bundle needs a path")
    text = bundle.dumps()
    bundle_from_dict(yaml.safe_load(text), path)  # never write what we could not load back
    try:
        _atomic_write(path, text.encode("utf-8"))
    except OSError as e:
        raise InputError(path, f"cannot write bundle ({e.strerror or e.__class__.__name__})") from None
    bundle.path = path
    return path


def session_file_path(bundle: Bundle, key: str) -> Path:
    """Where :func:`save_session` writes ``key``: ``<bundle folder>/<bundle stem>.sessions/<key with / as __>.npz``."""
    return bundle.path.parent / f"{bundle.path.stem}.sessions" / (key.replace("/", "__") + ".npz")


def save_session(bundle: Bundle, key: str, arrays: dict[str, np.ndarray], meta: dict | None = None) -> Path:
    """Store what a report needs (observations, residuals, per-view poses) next to the bundle as an ``.npz``
    and reference it from ``bundle.sessions[key]`` (save the bundle afterwards)."""
    if bundle.path is None:
        raise ValueError("save_session needs a bundle with a path")
    rel = session_file_path(bundle, key).relative_to(bundle.path.parent)
    buf = _io.BytesIO()
    import json

    np.savez_compressed(buf, __meta__=np.array(json.dumps(_plain(meta or {}))), **{k: np.asarray(v) for k, v in arrays.items()})
    try:
        _atomic_write(bundle.path.parent / rel, buf.getvalue(), keep_backup=False)
    except OSError as e:
        raise InputError(bundle.path.parent / rel, f"cannot write session file ({e.strerror or e.__class__.__name__})") from None
    bundle.sessions[key] = rel.as_posix()
    return bundle.path.parent / rel


def read_session_file(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays and metadata of one session file written by :func:`save_session` (InputError naming the file)."""
    import json
    import zipfile

    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k != "__meta__"}
            meta = json.loads(str(z["__meta__"])) if "__meta__" in z.files else {}
    except FileNotFoundError:
        raise InputError(p, "session file not found") from None
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:
        raise InputError(p, f"cannot read session file ({e.__class__.__name__})") from None
    return arrays, meta


def load_session(bundle: Bundle, key: str) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays and metadata saved by :func:`save_session` under ``key``."""
    if key not in bundle.sessions:
        raise InputError(bundle.path, f"no session {key!r} in the bundle (sessions: {', '.join(sorted(bundle.sessions)) or 'none'})")
    return read_session_file((bundle.path.parent if bundle.path else Path(".")) / bundle.sessions[key])

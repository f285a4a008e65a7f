"""Triangle-mesh files (field models): STL (binary or ASCII), PLY (ASCII or binary), OBJ — decoded here only.

:func:`read_mesh` returns a :class:`TriangleMesh` in metres: the unit is detected from the extent (a RoboMaster
field is 28 m long, so an extent above 200 is millimetres) or given (``units="mm"|"m"``). Every failure is one
:class:`radarcal.errors.InputError` naming the file ("not a mesh", "no triangles", ...).

:func:`read_field_sidecar` reads the optional YAML beside a field mesh (name, season, landmarks, structures,
``filter_mesh``, ``T_field_mesh``) — see ``docs/field.md``.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal.errors import InputError

__all__ = ["TriangleMesh", "read_mesh", "read_field_sidecar", "sidecar_path", "MESH_SUFFIXES", "UNITS"]

MESH_SUFFIXES = (".stl", ".ply", ".obj")
UNITS = {"m": 1.0, "mm": 1e-3, "cm": 1e-2}


@dataclass
class TriangleMesh:
    """Vertices (V,3) float64 in metres (frame of the file unless mapped), triangles (T,3) int64."""

    vertices: np.ndarray
    triangles: np.ndarray
    source: str = ""
    units: str = "m"
    sha256: str = ""

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, float).reshape(-1, 3)
        self.triangles = np.ascontiguousarray(self.triangles, np.int64).reshape(-1, 3)

    @property
    def corners(self) -> np.ndarray:
        """(T,3,3) vertex coordinates of every triangle."""
        return self.vertices[self.triangles]

    def normals(self) -> np.ndarray:
        """(T,3) unit normals (right-hand rule); zero rows for degenerate triangles."""
        c = self.corners
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)

    def areas(self) -> np.ndarray:
        c = self.corners
        return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)

    def transformed(self, T: np.ndarray) -> "TriangleMesh":
        """The mesh with every vertex mapped by the 4x4 ``T`` (a reflection flips the winding back)."""
        T = np.asarray(T, float)
        v = self.vertices @ T[:3, :3].T + T[:3, 3]
        tri = self.triangles if np.linalg.det(T[:3, :3]) > 0 else self.triangles[:, ::-1]
        return TriangleMesh(v, tri.copy(), self.source, self.units, self.sha256)

    def sample_surface(self, spacing: float, rng: np.random.Generator | None = None) -> np.ndarray:
        """Points (M,3) on the surface, about one per ``spacing``² (each triangle gets ≥ its 3 corners and centroid)."""
        rng = rng or np.random.default_rng(0)
        c = self.corners
        a = self.areas()
        keep = a > 0
        c, a = c[keep], a[keep]
        n = np.ceil(2.0 * a / spacing**2).astype(np.int64)
        idx = np.repeat(np.arange(len(c)), n)
        r1 = np.sqrt(rng.random(len(idx)))
        r2 = rng.random(len(idx))
        w0, w1, w2 = 1 - r1, r1 * (1 - r2), r1 * r2
        pts = w0[:, None] * c[idx, 0] + w1[:, None] * c[idx, 1] + w2[:, None] * c[idx, 2]
        # long thin triangles (walls): also sample their edges densely
        e = np.concatenate([c[:, [0, 1]], c[:, [1, 2]], c[:, [2, 0]]])
        ln = np.linalg.norm(e[:, 1] - e[:, 0], axis=1)
        m = np.ceil(ln / spacing).astype(np.int64) + 1
        ei = np.repeat(np.arange(len(e)), m)
        s = rng.random(len(ei))
        epts = e[ei, 0] + s[:, None] * (e[ei, 1] - e[ei, 0])
        return np.concatenate([pts, epts, c.reshape(-1, 3), c.mean(axis=1)])


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _stl(data: bytes, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if len(data) >= 84:
        n = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * n and n > 0:
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]), count=n, offset=84)
            return _index(rec["v"].astype(float).reshape(-1, 3))
    head = data[:512].lstrip().lower()
    if head.startswith(b"solid"):
        text = data.decode("ascii", errors="replace")
        nums = re.findall(r"vertex\s+(\S+)\s+(\S+)\s+(\S+)", text)
        if nums:
            try:
                v = np.array(nums, float)
            except ValueError:
                raise InputError(path, "not a mesh (ASCII STL with a vertex that is not three numbers)") from None
            if len(v) % 3:
                raise InputError(path, f"not a mesh (ASCII STL with {len(v)} vertices, not a multiple of 3)")
            return _index(v)
        raise InputError(path, "not a mesh (ASCII STL without facets)")
    raise InputError(path, "not a mesh (neither binary STL — size != 84 + 50 n — nor ASCII 'solid')")


def _index(corner_xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle-soup corners (3T,3) -> shared vertices (V,3), triangles (T,3)."""
    v, inv = np.unique(corner_xyz, axis=0, return_inverse=True)
    return v, inv.reshape(-1, 3)


def _obj(data: bytes, path: Path) -> tuple[np.ndarray, np.ndarray]:
    text = data.decode("utf-8", errors="replace")
    verts, faces = [], []
    for line in text.splitlines():
        if line.startswith("v "):
            verts.append(line.split()[1:4])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            faces.append(idx)
    if not verts or not faces:
        raise InputError(path, "not a mesh (OBJ without 'v' and 'f' lines)")
    try:
        v = np.array(verts, float)
    except ValueError:
        raise InputError(path, "not a mesh (OBJ vertex that is not three numbers)") from None
    tris = []
    for f in faces:
        f = [i - 1 if i > 0 else len(v) + i for i in f]
        tris.extend([f[0], f[k], f[k + 1]] for k in range(1, len(f) - 1))
    return v, np.array(tris, np.int64).reshape(-1, 3)


def _ply(data: bytes, path: Path) -> tuple[np.ndarray, np.ndarray]:
    from radarcal.io.ply import PLY_TYPES, read_ply_header

    head = read_ply_header(data, path, "not a mesh (PLY without 'ply' / 'end_header')")
    fmt, body_at = head.fmt, head.body_at
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(path, f"not a mesh (PLY format {fmt!r})")
    if any(e.unknown_types() for e in head.elements):
        raise InputError(path, "PLY has an unknown property type")
    elements = [(e.name, e.count, e.props) for e in head.elements]
    verts = faces = None
    if fmt == "ascii":
        lines = data[body_at:].decode("ascii", errors="replace").split("\n")
        pos = 0
        for name, count, props in elements:
            rows = lines[pos:pos + count]
            pos += count
            if name == "vertex":
                names = [p[-1] for p in props]
                try:
                    arr = np.array([r.split()[: len(names)] for r in rows], float)
                    verts = arr[:, [names.index("x"), names.index("y"), names.index("z")]]
                except (ValueError, IndexError):
                    raise InputError(path, "not a mesh (PLY vertex rows unreadable)") from None
            elif name == "face":
                tris = []
                for r in rows:
                    t = [int(x) for x in r.split()]
                    f = t[1: 1 + t[0]]
                    tris.extend([f[0], f[k], f[k + 1]] for k in range(1, len(f) - 1))
                faces = np.array(tris, np.int64).reshape(-1, 3)
    else:
        bo = head.byteorder
        off = body_at
        for name, count, props in elements:
            if all(p[0] != "list" for p in props):
                dt = np.dtype([(p[-1], bo + PLY_TYPES[p[0]]) for p in props])
                arr = np.frombuffer(data, dt, count=count, offset=off)
                off += dt.itemsize * count
                if name == "vertex":
                    verts = np.stack([arr["x"], arr["y"], arr["z"]], 1).astype(float)
            elif name == "face" and len(props) == 1:
                _, ct, it = props[0][:3]
                ct_dt, it_dt = np.dtype(bo + PLY_TYPES[ct]), np.dtype(bo + PLY_TYPES[it])
                n0 = int(np.frombuffer(data, ct_dt, 1, off)[0]) if count else 3
                # fast path: every face a triangle
                dt = np.dtype([("n", ct_dt), ("i", it_dt, (n0,))])
                arr = np.frombuffer(data, dt, count=count, offset=off)
                if n0 != 3 or np.any(arr["n"] != 3):
                    raise InputError(path, "PLY faces that are not all triangles are not supported (triangulate the mesh)")
                faces = arr["i"].astype(np.int64)
                off += dt.itemsize * count
            else:
                raise InputError(path, f"PLY element {name!r} with list properties is not supported")
    if verts is None or faces is None:
        raise InputError(path, "not a mesh (PLY without vertex and face elements)")
    return verts, faces


def read_mesh(path: str | os.PathLike, units: str = "auto") -> TriangleMesh:
    """A triangle mesh in metres. ``units``: ``auto`` (extent > 200 -> mm, else m), ``mm``, ``cm`` or ``m``."""
    path = Path(path)
    if units not in ("auto", *UNITS):
        raise InputError("--field-units", f"expected auto, mm, cm or m, got {units!r}")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "mesh file not found") from None
    except OSError as e:
        raise InputError(path, f"cannot read mesh file ({e.__class__.__name__})") from None
    suf = path.suffix.lower()
    if suf == ".stl":
        v, t = _stl(data, path)
    elif suf == ".obj":
        v, t = _obj(data, path)
    elif suf == ".ply":
        v, t = _ply(data, path)
    else:
        raise InputError(path, f"not a mesh file (expected {', '.join(MESH_SUFFIXES)})")
    if len(t) == 0:
        raise InputError(path, "not a mesh (no triangles)")
    if not np.all(np.isfinite(v)):
        raise InputError(path, "not a mesh (non-finite vertex coordinates)")
    if t.min() < 0 or t.max() >= len(v):
        raise InputError(path, "not a mesh (face index out of range)")
    ext = float(np.max(v.max(0) - v.min(0)))
    if ext <= 0:
        raise InputError(path, "not a mesh (all vertices coincide)")
    if units == "auto":
        units = "mm" if ext > 200.0 else "m"
    v = v * UNITS[units]
    return TriangleMesh(v, t, str(path), units, _sha256(data))


def sidecar_path(mesh_path: str | os.PathLike) -> Path | None:
    """``<mesh>.yaml`` / ``<stem>.yaml`` / ``<stem>.field.yaml`` beside the mesh, if one exists."""
    p = Path(mesh_path)
    for cand in (p.with_name(p.name + ".yaml"), p.with_suffix(".yaml"), p.with_suffix(".field.yaml")):
        if cand.is_file():
            return cand
    return None


def read_field_sidecar(path: str | os.PathLike) -> dict:
    """The sidecar YAML of a field mesh as a mapping (validated by :func:`radarcal.field.field_from_mesh`)."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, "field sidecar not found") from None
    except Exception as e:  # noqa: BLE001 - YAML/decoding errors -> one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else e.__class__.__name__
        raise InputError(path, f"cannot parse field sidecar ({first})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(path, "field sidecar: top level must be a mapping (name, season, landmarks, ...)")
    return data

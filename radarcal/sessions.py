"""Typed session files: what a calibration command keeps for its report, one dataclass per kind.

A session file (``<bundle>.sessions/<kind>__<name>.npz``, written by :func:`radarcal.bundle.save_session`) holds a
:class:`SessionRecord` subclass: fields annotated ``np.ndarray`` become arrays of the ``.npz`` under their own name,
``dict[str, np.ndarray]`` fields (per-scene arrays) become arrays named by their keys, everything else goes to the
JSON metadata, with ``kind`` and ``version``. The report reads the same dataclass back: exactly these names, no
aliases, no guessing. The kinds live beside their solvers: :class:`radarcal.intrinsics.session.IntrinsicsSession`
and ``StereoSession``, :class:`radarcal.extrinsics.lidar_camera_session.LidarCameraSession`,
:class:`radarcal.pnp.session.FieldPnPSession`.

Files named in a session (``PATH_FIELDS``: image and cloud files, as given on the command line) are stored relative to
the session file's folder when they exist, so a project folder moved as a whole (bundle, sessions, data) still finds
them; readers resolve them against the session file's folder first (:func:`resolve_session_path`).

Files written before ``kind`` existed are read when their names match (the commands wrote these names already).
"""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np

from radarcal.errors import InputError

__all__ = ["SessionRecord", "session_kind", "relative_to_session", "resolve_session_path"]

S = TypeVar("S", bound="SessionRecord")


def _kind_of_annotation(ann: Any) -> str:
    text = ann if isinstance(ann, str) else getattr(ann, "__name__", repr(ann))
    if text.startswith("dict[str, np.ndarray]"):
        return "array_dict"
    if "np.ndarray" in text or "ndarray" == text:
        return "array"
    return "meta"


@dataclasses.dataclass
class SessionRecord:
    """Base of the typed session files (see the module docstring). ``ARRAY_DICT_KEYS``: regular expression of the
    array names that belong to the class's one ``dict[str, np.ndarray]`` field."""

    KIND: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    ARRAY_DICT_KEYS: ClassVar[str] = r"$^"
    PATH_FIELDS: ClassVar[tuple[str, ...]] = ()  # fields holding file names (str, nested lists or arrays of str)

    def parts(self, session_dir: str | os.PathLike | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """(arrays, metadata) as stored; with ``session_dir`` the ``PATH_FIELDS`` relative to it (those that exist)."""
        arrays: dict[str, np.ndarray] = {}
        meta: dict[str, Any] = {"kind": self.KIND, "version": self.VERSION}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            if session_dir is not None and f.name in self.PATH_FIELDS:
                v = relative_to_session(v, session_dir)
            kind = _kind_of_annotation(f.type)
            if kind == "array":
                arrays[f.name] = np.asarray(v)
            elif kind == "array_dict":
                arrays.update({str(k): np.asarray(a) for k, a in v.items()})
            else:
                meta[f.name] = v
        return arrays, meta

    def save(self, bundle, key: str) -> Path:
        """Write as ``bundle.sessions[key]`` (save the bundle afterwards)."""
        from radarcal.bundle import save_session, session_file_path

        return save_session(bundle, key, *self.parts(session_file_path(bundle, key).parent if bundle.path is not None else None))

    @classmethod
    def from_parts(cls: type[S], arrays: dict[str, np.ndarray], meta: dict[str, Any], source: Any = "session") -> S:
        """The record from a session's arrays and metadata; ``InputError`` when the file is of another kind."""
        kind = meta.get("kind")
        if kind is not None and kind != cls.KIND:
            raise InputError(source, f"session of kind {kind!r}, expected {cls.KIND!r}")
        kw: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            k = _kind_of_annotation(f.type)
            if k == "array" and f.name in arrays:
                kw[f.name] = arrays[f.name]
            elif k == "array_dict":
                kw[f.name] = {n: a for n, a in arrays.items() if re.match(cls.ARRAY_DICT_KEYS, n)}
            elif k == "meta" and f.name in meta:
                kw[f.name] = meta[f.name]
        return cls(**kw)

    @classmethod
    def load(cls: type[S], bundle, key: str) -> S:
        from radarcal.bundle import load_session

        arrays, meta = load_session(bundle, key)
        return cls.from_parts(arrays, meta, bundle.sessions.get(key, key))


def relative_to_session(value: Any, session_dir: str | os.PathLike) -> Any:
    """File names in ``value`` (a str, nested lists / tuples, or an array of str) that exist, as paths relative to
    ``session_dir``; the others (not files, or on another drive) unchanged."""
    if isinstance(value, np.ndarray):
        return np.array([relative_to_session(str(x), session_dir) for x in value.ravel()], dtype=str).reshape(value.shape) if value.dtype.kind in "US" else value
    if isinstance(value, (list, tuple)):
        return [relative_to_session(x, session_dir) for x in value]
    if isinstance(value, (str, os.PathLike)) and str(value) and Path(value).exists():
        try:
            return Path(os.path.relpath(Path(value).resolve(), Path(session_dir).resolve())).as_posix()
        except ValueError:  # another drive
            return str(Path(value).resolve())
    return value


def resolve_session_path(name: str, session_dir: str | os.PathLike | None, *fallback_dirs: str | os.PathLike | None) -> Path | None:
    """A file named in a session: absolute; else relative to the session file's folder (how the commands store it),
    then to each of ``fallback_dirs`` (files written before paths were stored that way: the bundle's folder, the
    working folder). None when it is nowhere."""
    p = Path(name)
    if p.is_absolute():
        return p if p.exists() else None
    for d in (session_dir, *fallback_dirs):
        if d is not None:
            cand = Path(os.path.normpath(Path(d) / p))  # lexically: the folder before a '..' may be gone
            if cand.exists():
                return cand
    return p if p.exists() else None


def session_kind(key: str) -> str:
    """``intrinsics/cam0`` -> ``intrinsics``."""
    return key.partition("/")[0]

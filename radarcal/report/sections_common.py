"""Plumbing of the report sections: a figure adder that turns a failure into a note, files named in a session."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from radarcal.errors import InputError
from radarcal.report import intrinsics as ri
from radarcal.report.html import Section, Table

__all__ = ["FigureAdder", "note_missing_image", "str_list", "resolve_file", "read_image_file", "read_cloud_file", "camera_param_table"]


class FigureAdder:
    """Adds figures to a section, turning a failure into a note instead of losing the whole report."""

    def __init__(self, section: Section, skipped: list[str]):
        self.section = section
        self.skipped = skipped

    def __call__(self, label: str, make: Callable[[], Any], needs: dict[str, Any] | None = None, caption: str = "") -> None:
        missing = [k for k, v in (needs or {}).items() if v is None]
        if missing:
            msg = f"{self.section.title}: {label} skipped (session lacks {', '.join(missing)})"
            self.skipped.append(msg)
            self.section.add(f"{label}: not available (the session does not contain {', '.join(missing)}).")
            return
        try:
            self.section.add(make(), caption)
        except (ValueError, KeyError, IndexError, TypeError) as e:
            msg = f"{self.section.title}: {label} failed ({e.__class__.__name__}: {e})"
            self.skipped.append(msg)
            self.section.add(f"{label}: could not be drawn ({e}).")


def note_missing_image(section: Section, skipped: list[str], figure: str, image_name: str | None) -> None:
    """A figure drawn over an image has none: say why in the section and in the list of what was skipped."""
    why = f"{image_name} not found next to the session file or the bundle" if image_name else "the session names no image"
    skipped.append(f"{section.title}: {figure} drawn without the image ({why})")
    section.add(f"{figure}: drawn without the image ({why}).")


def str_list(a: Any) -> list[str]:
    if a is None:
        return []
    return [str(x) for x in np.asarray(a).ravel()]


def _bases(base) -> list[Path]:
    if base is None:
        return []
    if isinstance(base, (str, Path)):
        return [Path(base)]
    return [Path(b) for b in base if b is not None]


def resolve_file(name: str, base: Path | Sequence[Path | None] | None) -> Path | None:
    """A file named in a session: absolute, else relative to each of ``base`` in order (the session file's folder,
    then the bundle's), then to the working folder (:func:`radarcal.sessions.resolve_session_path`)."""
    from radarcal.sessions import resolve_session_path

    b = _bases(base)
    return resolve_session_path(name, *(b or [None]), Path.cwd())


def read_cloud_file(name: str, base: Path | Sequence[Path | None] | None) -> np.ndarray | None:
    """The points of a cloud (file or bag folder) named in a session, or None when it is not there / not readable."""
    p = resolve_file(name, base)
    if p is None:
        return None
    try:
        from radarcal.io.cloud_sources import read_scene_cloud

        return read_scene_cloud(p).points
    except InputError:
        return None


def read_image_file(name: str, base: Path | Sequence[Path | None] | None) -> np.ndarray | None:
    """An image named in a session (see :func:`resolve_file`), or None when it is not there / not readable."""
    p = resolve_file(name, base)
    if p is None or not p.is_file():
        return None
    try:
        from radarcal.io import read_image

        return read_image(p)
    except InputError:
        return None


def camera_param_table(name: str, entry) -> Table:
    cam = entry.camera
    dist_names = ["k1", "k2", "k3", "k4"] if cam.model == "fisheye" else ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"]
    names = ["fx", "fy", "cx", "cy"] + dist_names[: cam.dist.size]
    values = [cam.fx, cam.fy, cam.cx, cam.cy] + list(cam.dist)
    units = ["px"] * 4 + [""] * cam.dist.size
    sig = entry.sigma or {}
    rows = []
    for n, v, u in zip(names, values, units):
        s = sig.get(n)
        vs, ss = ri.format_value_sigma(float(v), None if s is None else float(s))
        rows.append([n, vs, ss, u])
    if entry.rms_px is not None:
        rows.append(["RMS", f"{entry.rms_px:.4f}", "", "px"])
    return Table(["parameter", "value", "σ", "unit"], rows, caption=f"{name}: {cam.model}, {cam.width}×{cam.height}")

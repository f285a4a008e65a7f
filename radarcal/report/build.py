"""Turn a bundle (and the session files its calibration commands saved next to it) into report sections.

This is the I/O edge of :mod:`radarcal.report`: it reads the typed session files (:mod:`radarcal.sessions`), the
images and clouds they name, and run track files, then calls the section builders (``intrinsics_section``,
``lidar_camera_section``, ``field_section``), which call the pure figure functions. Whatever a session lacks is
skipped with a note in the report, so a report can always be made from what is there.

Session keys: ``intrinsics/<camera>``, ``stereo/<cam0>_<cam1>``, ``lidar_camera/<camera>_<lidar>``,
``field_pnp/<camera>``; each is read by its dataclass with exactly the names its command writes (``docs/report.md``).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from radarcal.bundle import Bundle, read_session_file
from radarcal.camera import Camera
from radarcal.errors import InputError
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.intrinsics.session import IntrinsicsSession
from radarcal.pnp.session import FieldPnPSession
from radarcal.report.field_section import FieldData, field_data, field_drawing_args, field_section, read_tracks, run_section
from radarcal.report.html import Section, Table
from radarcal.report.intrinsics_section import IntrinsicsData, intrinsics_data, intrinsics_section, stereo_section
from radarcal.report.lidar_camera_section import LidarCameraData, lidar_camera_data, lidar_camera_section
from radarcal.report.radar_section import radar_lidar_section
from radarcal.report.sections_common import camera_param_table, read_cloud_file, read_image_file, resolve_file

__all__ = ["ReportContent", "build_report", "discover_sessions", "session_files", "session_base", "resolve_file", "read_tracks", "field_drawing_args", "IntrinsicsData", "intrinsics_data", "FieldData", "field_data", "LidarCameraData", "lidar_camera_data"]


@dataclass
class ReportContent:
    sections: list[Section] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # what could not be drawn and why

    @property
    def n_figures(self) -> int:
        return sum(1 for s in self.sections for it in s.items if hasattr(it[0] if isinstance(it, tuple) else it, "savefig"))


# --- sessions ----------------------------------------------------------------------------------------------------------
def discover_sessions(bundle: Bundle, session_dir: str | os.PathLike | None = None) -> dict[str, tuple[dict, dict]]:
    """All sessions: those referenced by the bundle (looked up in ``session_dir`` by file name when given, for a
    bundle whose session folder moved) plus any other ``*.npz`` in ``session_dir`` (key from the file name,
    ``intrinsics__cam0.npz`` → ``intrinsics/cam0``)."""
    return {k: (a, m) for k, (a, m, _) in session_files(bundle, session_dir).items()}


def session_files(bundle: Bundle, session_dir: str | os.PathLike | None = None) -> dict[str, tuple[dict, dict, Path]]:
    """As :func:`discover_sessions`, with the path of each session file (files it names are relative to its folder)."""
    out: dict[str, tuple[dict, dict, Path]] = {}
    sdir = Path(session_dir) if session_dir is not None else None
    if sdir is not None and not sdir.is_dir():
        raise InputError(sdir, "session directory not found")
    home = bundle.path.parent if bundle.path else Path(".")
    for key, rel in sorted(bundle.sessions.items()):
        p = sdir / Path(rel).name if sdir is not None and (sdir / Path(rel).name).is_file() else home / rel
        out[key] = (*read_session_file(p), p)
    if sdir is not None:
        for p in sorted(sdir.glob("*.npz")):
            key = p.stem.replace("__", "/")
            if key not in out:
                out[key] = (*read_session_file(p), p)
    return out


def session_base(bundle: Bundle, key: str) -> list[Path]:
    """Where files named in the bundle's session ``key`` are looked for, in order: the session file's folder (how the
    commands store them), then the bundle's folder (files written before); for :func:`resolve_file`."""
    home = bundle.path.parent if bundle.path else Path(".")
    return [home / Path(bundle.sessions[key]).parent, home] if key in bundle.sessions else [home]


def _overview(bundle: Bundle, skip_cameras: set[str] = frozenset()) -> Section:
    sec = Section("Bundle overview")
    path = str(bundle.path) if bundle.path else "(in memory)"
    sec.add(f"Bundle {path}: {len(bundle.cameras)} camera(s), {len(bundle.transforms)} transform(s), {len(bundle.sessions)} session file(s).")
    from radarcal.verdicts import forced_entries

    for flag in forced_entries(bundle):  # results stored against the tool's own verdict (--force)
        sec.add(f"WARNING: {flag}")
    for name, entry in sorted(bundle.cameras.items()):
        if name not in skip_cameras:  # those get their table in their intrinsics section
            sec.add(camera_param_table(name, entry))
    if bundle.transforms:
        from radarcal.geometry import T_to_xyz_rpy_deg

        rows = []
        for key, e in sorted(bundle.transforms.items()):
            with warnings.catch_warnings():  # gimbal lock of the rpy display is harmless here
                warnings.simplefilter("ignore")
                xyzrpy = T_to_xyz_rpy_deg(e.T)
            sig = e.sigma or {}
            sig_txt = ", ".join(f"{k}={v:.3g}" for k, v in sig.items() if isinstance(v, (int, float))) or "—"
            res = e.residual or {}
            res_txt = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in res.items() if isinstance(v, (int, float, str))) or "—"
            rows.append([key, e.method or "—", *(f"{v:.4f}" for v in xyzrpy[:3]), *(f"{v:.3f}" for v in xyzrpy[3:]), sig_txt, res_txt])
        sec.add(Table(["transform", "method", "x (m)", "y (m)", "z (m)", "roll (°)", "pitch (°)", "yaw (°)", "σ", "residual"], rows, caption="Transforms (T_a_b maps b into a)"))
    return sec


# --- the whole report --------------------------------------------------------------------------------------------------
# ``base``: where files named in the session are looked for, in order (the session file's folder, the bundle's)
def _intrinsics(bundle: Bundle, key: str, arrays: dict, meta: dict, content: ReportContent, base: list[Path]) -> None:
    cam_name = key.partition("/")[2]
    if cam_name in bundle.cameras:
        cam, entry = bundle.cameras[cam_name].camera, bundle.cameras[cam_name]
    else:
        s = IntrinsicsSession.from_parts(arrays, meta, key)
        if s.K is None or s.dist is None or s.image_size is None:
            content.skipped.append(f"{key}: camera {cam_name!r} not in the bundle")
            return
        cam, entry = Camera(tuple(int(v) for v in s.image_size[:2]), s.K, s.dist, s.camera_model or "pinhole"), None
    content.sections.append(intrinsics_section(cam_name, cam, arrays, meta, entry, None, content.skipped, base))


def _lidar_camera(bundle: Bundle, key: str, arrays: dict, meta: dict, content: ReportContent, base: list[Path]) -> None:
    s = LidarCameraSession.from_parts(arrays, meta, key)
    rest = key.partition("/")[2]
    cam_name = s.camera or rest.partition("_")[0]
    lidar_name = s.lidar or rest[len(cam_name) + 1 :]
    if cam_name not in bundle.cameras:
        content.skipped.append(f"{key}: camera {cam_name!r} not in the bundle")
        return
    T_b = bundle.T(cam_name, lidar_name) if bundle.has_T(cam_name, lidar_name) else None
    entry = bundle.transforms.get(f"T_{cam_name}_{lidar_name}")
    pairs = [p for p in s.pairs or [] if isinstance(p, (list, tuple)) and len(p) == 2]
    img = read_image_file(str(pairs[0][0]), base) if pairs else None
    pts = read_cloud_file(str(pairs[0][1]), base) if pairs else None
    content.sections.append(lidar_camera_section(key, bundle.cameras[cam_name].camera, arrays, meta, T_b, img, content.skipped, entry.sigma if entry else None, pts))


def _field_pnp(bundle: Bundle, key: str, arrays: dict, meta: dict, content: ReportContent, base: list[Path]) -> None:
    cam_name = key.partition("/")[2]
    s = FieldPnPSession.from_parts(arrays, meta, key)
    cam = bundle.cameras[cam_name].camera if cam_name in bundle.cameras else None
    T = bundle.T(cam_name, "field") if bundle.has_T(cam_name, "field") else None
    img = read_image_file(s.image, base) if s.image else None
    content.sections.append(field_section(cam_name, cam, arrays, meta, bundle.field(), T, img, content.skipped))


def _radar_lidar(bundle: Bundle, key: str, arrays: dict, meta: dict, content: ReportContent, base: list[Path]) -> None:
    content.sections.append(radar_lidar_section(key, arrays, meta, bundle.transforms, content.skipped))


_SECTIONS = {"intrinsics": _intrinsics, "lidar_camera": _lidar_camera, "field_pnp": _field_pnp, "radar_lidar": _radar_lidar}
_ORDER = {"intrinsics": 0, "stereo": 1, "lidar_camera": 2, "field_pnp": 3, "radar_lidar": 4}


def build_report(bundle: Bundle, session_dir: str | os.PathLike | None = None, tracks: str | os.PathLike | None = None, truth_tracks: str | os.PathLike | None = None) -> ReportContent:
    """All sections the bundle's sessions (and an optional run track file) allow."""
    content = ReportContent()
    sessions = session_files(bundle, session_dir)
    home = bundle.path.parent if bundle.path else None
    with_intrinsics = {k.partition("/")[2] for k in sessions if k.startswith("intrinsics/")}
    content.sections.append(_overview(bundle, skip_cameras=with_intrinsics))
    for key, (arrays, meta, path) in sorted(sessions.items(), key=lambda kv: (_ORDER.get(kv[0].partition("/")[0], 9), kv[0])):
        kind = key.partition("/")[0]
        # files named in the session: relative to its folder; when --session found it elsewhere, relative to the
        # folder the bundle puts it in (the data stayed with the bundle); then the bundle's folder (older files)
        base = [path.parent, *([home / Path(bundle.sessions[key]).parent] if key in bundle.sessions and home is not None else []), home]
        try:
            if kind in _SECTIONS:
                _SECTIONS[kind](bundle, key, arrays, meta, content, base)
            elif kind == "stereo":
                content.sections.append(stereo_section(key, arrays, meta, content.skipped))
            else:
                sec = Section(f"Session {key}")
                sec.add(f"No report section for this kind of session; arrays: {', '.join(sorted(arrays)) or 'none'}.")
                content.sections.append(sec)
        except InputError as e:  # a session of another kind under this key
            content.skipped.append(f"{key}: {e.message}")
    if tracks is not None:
        tt, tp = read_tracks(tracks)
        gt, gp = read_tracks(truth_tracks) if truth_tracks is not None else (None, None)
        content.sections.append(run_section(tt, tp, bundle.field(), gt, gp, content.skipped))
    return content

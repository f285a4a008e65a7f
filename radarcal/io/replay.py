"""The replay folder ``radarcal synth field`` writes (and a recording tool may write): ``images/`` and ``clouds/`` (times
from ``times.csv``), ``detections.jsonl``, ``truth.jsonl``, ``meta.json`` (``fps``, ``lidar_hz``, ``camera``,
``lidar``), ``calib.yaml``. Camera and cloud times are on one clock (``times.csv`` of both folders)."""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from radarcal.errors import InputError
from radarcal.io.cloud_sources import FolderCloudSource, timed_files
from radarcal.io.clouds import CLOUD_SUFFIXES

__all__ = ["ReplayFolder", "TruthLines", "open_replay_folder", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


@dataclass
class ReplayFolder:
    root: Path
    meta: dict
    frames: list[tuple[float, Path]]  # the images that exist
    clouds: list[tuple[float, Path]]
    detections: Path | None
    truth: Path | None
    bundle: Path | None
    timeline: list[tuple[float, str]] | None = None  # every camera frame (from detections.jsonl), images or not

    def cloud_source(self, quiet: bool = False) -> FolderCloudSource:
        """The recorded clouds as a cloud source (sensor: ``meta["lidar"]``)."""
        return FolderCloudSource(items=self.clouds, sensor=str(self.meta.get("lidar") or ""), quiet=quiet)

    def truth_by_frame(self) -> dict[str, dict]:
        out = {}
        if self.truth is None:
            return out
        with contextlib.closing(TruthLines(self.truth)) as lines:
            for d in lines:
                out[str(d.get("frame", d.get("t")))] = d
        return out


class TruthLines:
    """``truth.jsonl`` read lazily, one record (dict) per non-empty line in file order: an iterator that can be left
    and resumed (flat memory on long replays); :meth:`close` when done. The file is opened at construction."""

    def __init__(self, path: str | os.PathLike):
        self._f = open(path, encoding="utf-8")

    def __iter__(self) -> TruthLines:
        return self

    def __next__(self) -> dict:
        for line in self._f:
            if line.strip():
                return json.loads(line)
        raise StopIteration

    def close(self) -> None:
        self._f.close()


def _timeline(det: Path) -> list[tuple[float, str]] | None:
    out = []
    with open(det, encoding="utf-8") as f:
        for line in f:
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                out.append((float(d["t"]), str(d["frame"])))
            except (ValueError, KeyError, TypeError):
                return None  # no usable frame names: the image list drives the replay (DetectionsFile reports errors)
    out.sort(key=lambda x: x[0])
    return out or None


def replay_fields(folder: str | os.PathLike) -> dict:
    """The parts of a replay folder as keyword arguments of :class:`ReplayFolder` (for subclasses)."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(root, "replay folder not found")
    meta = {}
    if (root / "meta.json").is_file():
        try:
            meta = json.loads((root / "meta.json").read_text(encoding="utf-8"))
        except ValueError:
            raise InputError(root / "meta.json", "not valid JSON") from None
    fps = float(meta.get("fps", 30.0))
    hz = float(meta.get("lidar_hz", 10.0))
    multi = not (root / "images").is_dir() and (root / "cameras").is_dir() and bool(meta.get("cameras"))  # cameras/<name>/ (issue #19)
    frames = [] if multi else timed_files(root / "images", IMAGE_SUFFIXES, fps, "image")
    clouds = timed_files(root / "clouds", CLOUD_SUFFIXES, hz, "point-cloud") if (root / "clouds").is_dir() else []
    det = root / "detections.jsonl"
    det = det if det.is_file() else None
    truth = root / "truth.jsonl"
    bundle = next((root / n for n in ("calib.yaml", "bundle.yaml") if (root / n).is_file()), None)
    return dict(root=root, meta=meta, frames=frames, clouds=clouds, detections=det, truth=truth if truth.is_file() else None, bundle=bundle,
                timeline=_timeline(det) if det else None)  # fmt: skip


def open_replay_folder(folder: str | os.PathLike) -> ReplayFolder:
    """Read a replay folder's index (files and times; nothing is decoded yet)."""
    return ReplayFolder(**replay_fields(folder))

"""Cloud sources: streams of :class:`radarcal.io.clouds.Cloud` in time order, the one way every command reads clouds.

A :class:`CloudSource` is iterated (clouds in non-decreasing ``t``), then closed; its ``skipped`` counter says what it
left out and why (an unreadable file, an undecodable bag message, a message out of time order) — a bad input in the
middle of a stream is reported on stderr and skipped, it never stops the match loop. Implementations:

- :class:`FolderCloudSource`: a folder of ``.pcd/.ply/.bin/.npy`` files, times from ``times.csv`` (``file,t``), else
  from numeric file names (seconds ``1700000000.123`` or 19-digit nanoseconds, kept absolute), else index / ``hz``;
- :class:`radarcal.io.bags.BagCloudSource`: a ROS1 ``.bag`` / ROS2 bag (Livox CustomMsg, PointCloud2), header stamps
  kept absolute;
- the replay folder of ``radarcal synth field`` (:func:`radarcal.io.replay.open_replay_folder`): a folder source over
  its ``clouds/``.

A *live* source (Livox UDP) is instead started and polled: ``start()``, a non-blocking ``poll() -> list[Cloud]``,
``close()``. Time stamps are never changed by a source; pairing with camera frames adds an explicit clock offset
(``radarcal.runtime.sources.merge_by_time``).

:func:`read_scene_cloud` is the reader for calibration commands (``lidar-camera``, ``radar-lidar``): one static
scene from a cloud file or from every cloud of a bag topic, merged.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Protocol, runtime_checkable

import numpy as np

from radarcal.errors import InputError
from radarcal.io.clouds import CLOUD_SUFFIXES, Cloud, read_cloud

__all__ = ["CloudSource", "Skips", "FolderCloudSource", "open_cloud_source", "read_scene_cloud", "timed_files", "read_times", "BAG_SUFFIXES"]

BAG_SUFFIXES = (".bag", ".mcap", ".db3")


@dataclass
class Skips:
    """What a source skipped and why: a count per reason and the first ``keep`` messages (each also written to
    stderr as ``warning: <file>: <problem> (skipped)`` unless ``quiet``)."""

    counts: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)
    keep: int = 20
    quiet: bool = False

    def add(self, reason: str, err: Exception | str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        if len(self.examples) < self.keep:
            self.examples.append(str(err))
        if not self.quiet:
            sys.stderr.write(f"warning: {err} (skipped)\n")

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def to_dict(self) -> dict:
        return {"total": self.total, "by_reason": dict(self.counts), "examples": list(self.examples)}


@runtime_checkable
class CloudSource(Protocol):
    """Clouds in non-decreasing time order; ``skipped`` counts what was left out and why; ``close()`` frees files."""

    skipped: Skips

    def __iter__(self) -> Iterator[Cloud]: ...

    def close(self) -> None: ...


# --- times of the files in a folder ----------------------------------------------------------------------------------
def read_times(folder: Path) -> dict[str, float]:
    """``times.csv`` (``file,t`` rows, optional header) of a folder; {} when there is none."""
    p = folder / "times.csv"
    if not p.is_file():
        return {}
    out = {}
    try:
        with open(p, newline="", encoding="utf-8") as f:
            for i, row in enumerate(csv.reader(f)):
                if not row or (i == 0 and not _is_float(row[-1])):
                    continue
                if len(row) < 2 or not _is_float(row[1]):
                    raise InputError(p, f"row {i + 1}: expected 'file,t' with t in seconds")
                out[row[0].strip()] = float(row[1])
    except OSError as e:
        raise InputError(p, f"cannot read ({e.__class__.__name__})") from None
    return out


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _stem_time(stem: str) -> float | None:
    """Time from a numeric file name: seconds (``1700000000.123``) or nanoseconds (16-20 digits)."""
    if re.fullmatch(r"\d{16,20}", stem):
        return int(stem) * 1e-9
    if re.fullmatch(r"\d+\.\d+", stem):
        return float(stem)
    return None


def timed_files(folder: Path, suffixes: tuple[str, ...], rate_hz: float, what: str) -> list[tuple[float, Path]]:
    """The files of ``folder`` with those suffixes and their times (s), sorted by time: ``times.csv`` when present,
    else numeric file names (absolute, as recorded), else ``index / rate_hz`` from 0."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, f"{what} folder not found")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes)
    if not files:
        raise InputError(folder, f"no {what} files ({', '.join(suffixes)})")
    times = read_times(folder)
    stem_times = [_stem_time(p.stem) for p in files]
    use_stems = not times and all(s is not None for s in stem_times)
    out = []
    for i, p in enumerate(files):
        if times:
            if p.name not in times:
                raise InputError(folder / "times.csv", f"no time for {p.name}")
            t = times[p.name]
        elif use_stems:
            t = float(stem_times[i])
        else:
            t = i / rate_hz
        out.append((t, p))
    out.sort(key=lambda x: x[0])
    return out


# --- folders ---------------------------------------------------------------------------------------------------------
class FolderCloudSource:
    """Cloud files of a folder in time order (see :func:`timed_files`); unreadable files are skipped and counted."""

    def __init__(self, folder: str | os.PathLike | None = None, hz: float = 10.0, sensor: str = "", items: list[tuple[float, Path]] | None = None, quiet: bool = False):
        self.items = items if items is not None else timed_files(Path(folder), CLOUD_SUFFIXES, hz, "point-cloud")
        self.sensor = sensor
        self.skipped = Skips(quiet=quiet)

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self) -> Iterator[Cloud]:
        for t, p in self.items:
            try:
                c = read_cloud(p)
            except InputError as e:
                self.skipped.add("unreadable cloud file", e)
                continue
            yield dataclasses.replace(c, t=t, sensor=self.sensor, name=p.name)

    def close(self) -> None:
        pass


def open_cloud_source(spec: str | os.PathLike, topic: str | None = None, hz: float = 10.0, sensor: str = "") -> CloudSource:
    """A recorded cloud source: a folder of cloud files, or a ROS1/ROS2 bag (file, ROS2 bag directory, .mcap, .db3)."""
    p = Path(spec)
    if p.is_dir() and not (p / "metadata.yaml").exists():
        return FolderCloudSource(p, hz, sensor)
    if p.exists():
        from radarcal.io.bags import BagCloudSource

        return BagCloudSource(p, topic, sensor)
    raise InputError(str(spec), "cloud source not found (expected a folder of clouds or a ROS bag)")


def read_scene_cloud(path: str | os.PathLike, topic: str | None = None, max_clouds: int | None = None) -> Cloud:
    """One static scene in the LiDAR frame: a cloud file (.pcd .ply .bin .npy) as it is, or a bag's clouds on
    ``topic`` (needed when the bag has several cloud topics) merged — a Livox non-repeating scan fills in over
    time, so accumulating a still scene gives the dense cloud calibration wants. ``max_clouds``: the first that many.
    The result's ``t`` is the last merged cloud's stamp."""
    path = Path(path)
    if path.suffix.lower() in CLOUD_SUFFIXES:
        return dataclasses.replace(read_cloud(path), name=path.name)
    if not path.exists():
        raise InputError(path, "point cloud not found")
    if not (path.suffix.lower() in BAG_SUFFIXES or (path / "metadata.yaml").exists()):
        raise InputError(path, f"unknown point-cloud format {path.suffix!r} (expected {', '.join(CLOUD_SUFFIXES)} or a ROS bag)")
    from radarcal.io.bags import BagCloudSource

    src = BagCloudSource(path, topic, quiet=True)
    try:
        if topic is None and len(src.topics) > 1:
            raise InputError(path, f"several cloud topics ({', '.join(src.topics)}): choose one with --cloud-topic")
        parts = []
        for c in src:
            parts.append(c)
            if max_clouds is not None and len(parts) >= max_clouds:
                break
    finally:
        src.close()
    if not parts:
        why = f" ({src.skipped.examples[0]})" if src.skipped.examples else ""
        raise InputError(path, f"no readable cloud on {', '.join(src.topics)}{why}")
    inten = np.concatenate([c.intensity for c in parts]) if all(c.intensity is not None for c in parts) else None
    return Cloud(np.concatenate([c.points for c in parts]), inten, t=parts[-1].t, name=f"{path.name}:{parts[0].name.split('@')[0]} ({len(parts)} clouds)")

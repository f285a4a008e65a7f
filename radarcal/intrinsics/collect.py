"""The I/O edge of ``radarcal intrinsics``: expand SOURCE arguments, read images / video frames, and detect the
board in parallel (``concurrent.futures.ProcessPoolExecutor``). Returns one :class:`ViewInput` per image/frame
with either a :class:`~radarcal.intrinsics.detect.Detection` or the reason it could not be read.

Workers come from a ``forkserver`` (clean processes; forking after OpenCV/BLAS threads ran can deadlock), so a
script calling :func:`detect_files` with ``workers > 1`` needs the usual ``if __name__ == "__main__":`` guard;
without it the pool fails and detection falls back to this process."""

from __future__ import annotations

import glob
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable

import cv2
import numpy as np

from radarcal.board import BoardSpec
from radarcal.errors import InputError
from radarcal.io.images import read_image
from radarcal.intrinsics.detect import Detection, choose_charuco_layout, detect_board, diagnose_board_size
from radarcal.intrinsics.select import DESCRIPTOR_NAMES, TARGET_RANGES, novel_mask, view_descriptor

__all__ = ["ViewInput", "CameraViews", "IMAGE_EXTS", "VIDEO_EXTS", "expand_sources", "check_sources", "collect_camera", "detect_files", "sample_video", "decide_layout",
           "diagnose", "LiveCoverage"]

IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"}
VIDEO_EXTS = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg"}


@dataclass
class ViewInput:
    name: str  # file path, or "video.mp4#frame123"
    detection: Detection | None  # None when unreadable
    error: str = ""  # "unreadable: ..." when the file could not be read


@dataclass
class CameraViews:
    """One camera's inputs: its name in the bundle, the views, the board (ChArUco layout decided), the layout
    evidence (empty unless decided here) and the files read (for provenance and to name in errors)."""

    name: str
    views: list[ViewInput]
    board: BoardSpec
    layout_info: dict = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)


def expand_sources(sources: Iterable[str]) -> tuple[list[Path], list[Path]]:
    """SOURCE arguments (files, folders, globs, videos) -> (image files, video files), sorted, de-duplicated.
    Unknown extensions inside folders are skipped; an explicit file with an unknown extension is treated as an
    image (and reported unreadable if it is not one). A source matching nothing raises InputError."""
    images: list[Path] = []
    videos: list[Path] = []
    for s in sources:
        p = Path(s)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_EXTS | VIDEO_EXTS)
            if not found:
                raise InputError(p, "folder holds no images or videos")
        elif p.is_file():
            found = [p]
        else:
            found = sorted(Path(q) for q in glob.glob(s) if Path(q).is_file())
            if not found:
                raise InputError(s, "no such file, folder or glob match")
        for q in found:
            (videos if q.suffix.lower() in VIDEO_EXTS else images).append(q)
    seen = set()
    uniq = lambda xs: [x for x in xs if not (str(x.resolve()) in seen or seen.add(str(x.resolve())))]  # noqa: E731
    return uniq(images), uniq(videos)


def _worker_init() -> None:
    cv2.setNumThreads(1)  # parallelism is across images; OpenCV's own threads would only contend


def _pool(workers: int) -> ProcessPoolExecutor:
    """Workers from a clean ``forkserver`` (``spawn`` where unavailable): forking a process whose OpenCV/BLAS
    thread pools have run can deadlock the child (seen here under pytest)."""
    import multiprocessing as mp

    method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
    ctx = mp.get_context(method)
    if method == "forkserver":  # import the detector once in the server; workers fork from it ready to go
        ctx.set_forkserver_preload(["radarcal.intrinsics.collect"])
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init)


def _truncated(path: str) -> str | None:
    """A cheap end check for PNG (the IEND chunk closes every complete file): names a truncated PNG precisely and
    keeps libpng from printing to stderr mid-run. JPEGs are left to the decoder (cameras append data after EOI)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 64))
            tail = f.read()
    except OSError:
        return None
    if head.startswith(b"\x89PNG\r\n\x1a\n") and b"IEND" not in tail:
        return "truncated PNG (no IEND chunk)"
    return None


def _detect_one(path: str, board: BoardSpec) -> ViewInput:
    cut = _truncated(path)
    if cut:
        return ViewInput(path, None, f"unreadable: {cut}")
    try:
        gray = read_image(path, grayscale=True)
    except InputError as e:
        return ViewInput(path, None, f"unreadable: {e.message}")
    return ViewInput(path, detect_board(gray, board))


def _read_gray(path: Path) -> np.ndarray | None:
    data = np.fromfile(path, dtype=np.uint8)
    return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None


def decide_layout(paths: list[Path], board: BoardSpec, sample: int = 6) -> tuple[BoardSpec, dict]:
    """For ChArUco with ``legacy=None``: try both layouts on up to ``sample`` evenly spaced images."""
    if board.kind != "charuco" or board.legacy is not None or not paths:
        return board, {}
    idx = np.unique(np.linspace(0, len(paths) - 1, min(sample, len(paths))).round().astype(int))
    grays = [g for g in (_read_gray(paths[i]) for i in idx) if g is not None]
    legacy, counts = choose_charuco_layout(grays, board)
    info = {"legacy": legacy, "corners_new_layout": counts[False], "corners_legacy_layout": counts[True]}
    return (board if legacy is None else replace(board, legacy=legacy)), info


def detect_files(paths: list[Path], board: BoardSpec, workers: int = 2, on_done: Callable[[int, int, ViewInput], None] | None = None) -> list[ViewInput]:
    """Detect ``board`` in every file, ``workers`` processes in parallel (1 = in this process). Input order kept.
    ``on_done(k, n, view)`` is called as each file finishes (progress, live coverage)."""
    names = [str(p) for p in paths]
    out: list[ViewInput | None] = [None] * len(names)
    if workers <= 1 or len(names) < 2:
        for i, n in enumerate(names):
            out[i] = _detect_one(n, board)
            if on_done:
                on_done(i + 1, len(names), out[i])
        return out  # type: ignore[return-value]
    try:
        with _pool(workers) as ex:
            futs = {ex.submit(_detect_one, n, board): i for i, n in enumerate(names)}
            for k, f in enumerate(as_completed(futs), 1):
                i = futs[f]
                try:
                    out[i] = f.result()
                except BrokenProcessPool:
                    raise
                except Exception as e:  # noqa: BLE001 - one bad file must not end the run
                    out[i] = ViewInput(names[i], None, f"unreadable: {e.__class__.__name__}: {e}")
                if on_done:
                    on_done(k, len(names), out[i])
    except (BrokenProcessPool, RuntimeError, OSError):
        # no worker processes (e.g. a script without the ``if __name__ == "__main__":`` guard): do it here
        return detect_files(paths, board, 1, on_done)
    return out  # type: ignore[return-value]


def sample_video(path: Path, board: BoardSpec, max_candidates: int = 150, novelty: float = 0.2, sharpness_limit_px: float = 4.0, workers: int = 2) -> list[ViewInput]:
    """Frames of a video: ``max_candidates`` evenly spaced frames are detected (in parallel batches); frames
    that are blurred (edge width > ``sharpness_limit_px``) or not novel (ROS gate, L1 > ``novelty`` in X/Y/Size/
    Skew) are dropped. Returns the kept frames as views named ``<video>#frame<N>``."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(path, "cannot open video (corrupt or unsupported codec)")
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    step = max(1, n // max_candidates) if n > 0 else 1
    frames: list[tuple[int, np.ndarray]] = []
    i = 0
    while True:
        ok = cap.grab()
        if not ok:
            break
        if i % step == 0:
            ok, img = cap.retrieve()
            if ok and img is not None:
                frames.append((i, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img))
        i += 1
        if len(frames) >= max_candidates:
            break
    cap.release()
    if not frames:
        raise InputError(path, "no frames could be decoded")
    if workers > 1 and len(frames) > 1:
        with _pool(workers) as ex:
            dets = list(ex.map(detect_board, [f for _, f in frames], [board] * len(frames), chunksize=4))
    else:
        dets = [detect_board(f, board) for _, f in frames]
    views = []
    descs = []
    for (k, _f), d in zip(frames, dets):
        if d.ok and not (d.edge_width_px > sharpness_limit_px):
            views.append(ViewInput(f"{path}#frame{k}", d))
            descs.append(view_descriptor(d.uv, d.ids, board.grid_shape, d.image_size))
    if not views:
        return []
    keep = novel_mask(np.array(descs), novelty)
    return [v for v, k in zip(views, keep) if k]


def diagnose(paths: list[Path], board: BoardSpec, sample: int = 3) -> str | None:
    """A hint when no image shows the given board (see :func:`detect.diagnose_board_size`)."""
    for p in paths[:sample]:
        g = _read_gray(p)
        if g is None:
            continue
        hint = diagnose_board_size(g, board)
        if hint:
            return f"{hint} (in {p.name})"
    return None


def views_from_corner_file(path: Path, board: BoardSpec, image_size: tuple[int, int], min_fraction: float = 0.2) -> list[ViewInput]:
    """Views from another tool's corner file (mrcal ``.vnl`` or CSV, see :mod:`radarcal.io.corner_files`) as if
    detected here: a view with fewer than ``max(6, min_fraction * corners)`` found corners is kept but marked unusable."""
    from radarcal.io.corner_files import read_corner_file

    need = max(6, int(np.ceil(min_fraction * board.n_corners)))
    views = []
    for v in read_corner_file(path, board.n_corners):
        ok = len(v.ids) >= need
        det = Detection(ok, v.uv, v.ids, tuple(image_size), method="corner file", reason="" if ok else f"only {len(v.ids)} of {board.n_corners} corners in the file")
        views.append(ViewInput(v.name, det))
    return views


def check_sources(sources: list[str]) -> None:
    """Every SOURCE exists (:func:`expand_sources`), and a file named explicitly (not found in a folder or by a glob,
    where unreadable frames are only rejected views) is a readable image or a video (``InputError`` naming it)."""
    expand_sources(sources)
    for s in sources:
        p = Path(s)
        if p.is_file() and p.suffix.lower() not in VIDEO_EXTS:
            read_image(p, grayscale=True)


def collect_camera(name: str, sources: list[str], board: BoardSpec, workers: int = 2, on_done: Callable[[int, int, ViewInput], None] | None = None,
                   log: Callable[[str], None] = lambda msg: None) -> CameraViews:
    """The views of one camera from SOURCE arguments: the ChArUco layout decided on a sample of the images, the
    board detected in every image (``workers`` processes; ``on_done`` as in :func:`detect_files`) and in the sharp,
    novel frames of every video."""
    images, videos = expand_sources(sources)
    board, layout_info = decide_layout(images, board)
    views = detect_files(images, board, workers, on_done) if images else []
    for v in videos:
        log(f"sampling frames of {v} ...")
        views += sample_video(v, board, workers=workers)
    return CameraViews(name, views, board, layout_info, images + videos)


class LiveCoverage:
    """ROS-style live coverage while detecting: ``add(view)`` then :meth:`bars` (``X ███·· Y ...``) of the boards found so far."""

    def __init__(self, board: BoardSpec):
        self.board, self.descriptors = board, []

    def add(self, v: ViewInput) -> None:
        d = v.detection
        if d is not None and d.ok:
            self.descriptors.append(view_descriptor(d.uv, d.ids, self.board.grid_shape, d.image_size))

    def bars(self, width: int = 5) -> str:
        if not self.descriptors:
            return ""
        a = np.array(self.descriptors)
        prog = np.minimum((a.max(axis=0) - a.min(axis=0)) / TARGET_RANGES, 1.0)
        return " ".join(f"{nm} " + "█" * int(round(p * width)) + "·" * (width - int(round(p * width))) for nm, p in zip(DESCRIPTOR_NAMES, prog))

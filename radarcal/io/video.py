"""Video files through OpenCV: :class:`VideoFile` reads one (frames with the container's times), :class:`VideoFileWriter`
writes one (``.mp4``: mp4v, else MJPG). Live cameras are devices: :mod:`radarcal.io.camera_live`."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from radarcal.errors import InputError

__all__ = ["VideoFile", "VideoFileWriter"]


class VideoFile:
    """A video opened for reading (``InputError(source, cannot_open)`` when OpenCV cannot open it). ``fps``: the
    container's rate (30 when it does not say)."""

    def __init__(self, source: str, cannot_open: str = "cannot open video"):
        import cv2

        self._cap = cv2.VideoCapture(source)
        if not self._cap.isOpened():
            raise InputError(source, cannot_open)
        self.fps = self._cap.get(cv2.CAP_PROP_FPS) or 30.0

    def frames(self, fps: float | None = None) -> Iterator[tuple[float, np.ndarray]]:
        """(t seconds, BGR image) of every frame in order: ``t`` from the container's position, ``index / fps`` (``fps``
        given, else the container's) for the first frame and when it has none. Released at the end."""
        import cv2

        rate = fps or self.fps
        i = 0
        try:
            while True:
                ok, img = self._cap.read()
                if not ok:
                    break
                ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
                yield (ms / 1000.0 if ms and ms > 0 and i > 0 else i / rate), img
                i += 1
        finally:
            self._cap.release()

    def close(self) -> None:
        self._cap.release()


class VideoFileWriter:
    """A video file written frame by frame at ``fps``; opened by the first frame (its size); :meth:`close` finishes it."""

    def __init__(self, path: str | os.PathLike, fps: float = 30.0):
        self.path, self.fps, self._writer = Path(path), float(fps), None

    def write(self, img: np.ndarray) -> None:
        import cv2

        if self._writer is None:
            fourcc = cv2.VideoWriter_fourcc(*("mp4v" if self.path.suffix.lower() == ".mp4" else "MJPG"))
            self._writer = cv2.VideoWriter(str(self.path), fourcc, self.fps, (img.shape[1], img.shape[0]))
        self._writer.write(img)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()

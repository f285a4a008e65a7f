"""The results file of ``radarcal run`` (``--out``): JSON lines, one compact object per camera frame
(:meth:`radarcal.runtime.pipeline.FrameResult.to_dict`), written as the loop goes."""

from __future__ import annotations

import json
import os

__all__ = ["RunResultsWriter"]


class RunResultsWriter:
    """Opens (truncates) ``path`` at construction; :meth:`write` appends one record as one line; :meth:`close`."""

    def __init__(self, path: str | os.PathLike):
        self._f = open(path, "w", encoding="utf-8")

    def write(self, record: dict) -> None:
        self._f.write(json.dumps(record, separators=(",", ":")) + "\n")

    def close(self) -> None:
        self._f.close()

"""The precomputed detections file (``--detections``, a replay's ``detections.jsonl``): one JSON line per camera frame
``{"t", "frame"?, "boxes": [{"xyxy", "label"?, "score"?, "dead"?, "armour"?, "number"?}]}``, ``t`` in seconds on
the camera clock, ``xyxy`` in image pixels."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radarcal.errors import InputError, read_text

__all__ = ["DetectionLine", "read_detections_file"]


@dataclass
class DetectionLine:
    """One line: the frame's time (s), its name when the line has one, and its boxes as plain records
    ``{"xyxy": (4,) float pixels, "label": str, "score": float, "dead": bool, "armour": str | None, "number": str | None}``."""

    t: float
    frame: str | None
    boxes: list[dict]


def read_detections_file(path: str | os.PathLike) -> list[DetectionLine]:
    """Every line of the file in file order; ``InputError`` naming the file (and the line) when it is missing, a line
    is not a detection record (non-finite time, box or score included) or there is none."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "detections file not found")
    lines = []
    for i, line in enumerate(read_text(path, "detections file").splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            t = float(d["t"])
            boxes = [{"xyxy": np.asarray(b["xyxy"], float).reshape(4), "label": str(b.get("label", "")), "score": float(b.get("score", 1.0)),
                      "dead": bool(b.get("dead", False)), "armour": b.get("armour"), "number": b.get("number")} for b in d.get("boxes", [])]  # fmt: skip
            if not (np.isfinite(t) and all(np.all(np.isfinite(b["xyxy"])) and np.isfinite(b["score"]) for b in boxes)):
                raise ValueError("non-finite time, box or score")
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise InputError(path, f"line {i}: not a detection record ({e.__class__.__name__}: {e})") from None
        lines.append(DetectionLine(t, str(d["frame"]) if "frame" in d else None, boxes))
    if not lines:
        raise InputError(path, 'no detection records (expected one JSON line per frame: {"t", "frame", "boxes"})')
    return lines

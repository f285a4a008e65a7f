"""Robot -> armour -> number recognition, as the leading radar stations do it (T-DT 2024, HKUST 2025, HNURM 2026):
robot boxes on the full frame, an armour detector on each robot crop (with a grey / dead class), then a small
number classifier on each armour crop, so that the label comes from the armour, not the robot's silhouette.

Without ``armour`` the number classifier reads the robot crops directly (a detector + classifier pair, HUST 2025).
Every stage is batched: all robot crops of all frames in one armour run (each crop letterboxed to the armour model's
input on its own), all armour crops in one number run (plain resize to the classifier's input, grey when it has one
channel). Labels combine into ``red_3``: colour from the armour (else the robot detector's label), number from the
number classifier (else the armour's label, else the robot's). A grey / dead armour marks the robot ``dead``.
"""

from __future__ import annotations

import os
import re
import time

import numpy as np

from radarcal.errors import InputError
from radarcal.io.detector_files import class_names_from
from radarcal.runtime.detector import Detection, OnnxDetector, OnnxModel, to_tensor

__all__ = ["NumberClassifier", "Recogniser", "FrameDetector", "DetectAhead", "parse_armour_label", "parse_number_label", "combine_label"]

_COLOURS = {"red": "red", "r": "red", "blue": "blue", "b": "blue", "grey": "grey", "gray": "grey", "dead": "grey", "purple": "grey", "g": "grey",
            "black": "grey", "none": "grey"}  # fmt: skip
_NUMBER_WORDS = {"hero": 1, "engineer": 2, "infantry3": 3, "infantry4": 4, "infantry5": 5, "standard3": 3, "standard4": 4, "standard5": 5,
                 "aerial": 6, "drone": 6, "sentry": 7, "guard": 7}  # fmt: skip
_NOT_ROBOT = {"outpost", "base", "negative", "neg", "none", "background", "bg", "0", "false", "unknown"}


def parse_number_label(label: str | None) -> int | None:
    """Robot number 1..9 from a number-classifier label (``3``, ``B3``, ``sentry``, ``infantry4``); None for labels
    that are no robot (``negative``, ``outpost``, ``base``, ``0``)."""
    if label is None:
        return None
    s = str(label).strip().lower()
    if s in _NOT_ROBOT:
        return None
    if s in _NUMBER_WORDS:
        return _NUMBER_WORDS[s]
    m = re.search(r"(\d+)$", s)
    if m and 1 <= int(m.group(1)) <= 9:
        return int(m.group(1))
    return None


def parse_armour_label(label: str | None) -> tuple[str | None, int | None, bool]:
    """(colour red|blue|grey or None, number or None, dead) from an armour class name: ``red``, ``blue``, ``dead``,
    ``grey``, ``R3``, ``B1``, ``red_3``, ``armor_blue_sentry``, ``purple``."""
    if label is None:
        return None, None, False
    s = re.sub(r"^armou?r[_\- ]?", "", str(label).strip().lower())
    if s in _COLOURS:
        return _COLOURS[s], None, _COLOURS[s] == "grey"
    parts = re.split(r"[_\- ]+", s)
    m = re.match(r"^([a-z]+)(\d+)$", s)
    if len(parts) >= 2 and parts[0] in _COLOURS:
        head, tail = parts[0], "_".join(parts[1:])
    elif m and m.group(1) in _COLOURS:
        head, tail = m.group(1), m.group(2)
    else:  # no colour, e.g. "sentry"
        return None, parse_number_label(s), False
    colour = _COLOURS[head]
    return colour, parse_number_label(tail), colour == "grey"


def combine_label(robot_label: str, armour_label: str | None, number_label: str | None) -> tuple[str, bool]:
    """(label, dead) of a robot from what the three stages said. Colour: the armour's red / blue, else the robot
    label's; number: the classifier's, else the armour's, else the robot label's. Without colour or number the
    robot label stays (``red_unknown`` when only the colour is known)."""
    r_colour, r_number, _ = parse_armour_label(robot_label)
    a_colour, a_number, dead = parse_armour_label(armour_label)
    colour = a_colour if a_colour in ("red", "blue") else (r_colour if r_colour in ("red", "blue") else (a_colour or r_colour))
    number = parse_number_label(number_label) or a_number or r_number
    if armour_label is None and number_label is None:
        return robot_label, False
    if colour and number:
        return f"{colour}_{number}", dead
    if colour:
        return f"{colour}_unknown", dead
    return robot_label, dead


class NumberClassifier:
    """A number classifier on armour crops: input N x C x H x W (C = 1 grey or 3 RGB, 0..1, plain resize), output
    N x classes (probabilities, or logits -> softmax). Class names from ``class_names`` or the metadata ``names``
    (default ``1..C``)."""

    def __init__(self, path: str | os.PathLike, class_names: list[str] | None = None, names_source=None, threads: int = 0, spin: bool = False,
                 providers=None):  # fmt: skip
        self.model = OnnxModel(path, "number classifier", threads, spin, providers, channels=(1, 3), default_size=64)
        self.path = self.model.path
        out = self.model.outputs[0][1]
        if len(out) != 2 or len(self.model.outputs) != 1:
            raise InputError(self.path, f"number classifier: expected one N x classes output, got {self.model.outputs[0][0]} {'x'.join(map(str, out))}")
        nc = out[1] if isinstance(out[1], int) else None
        names = list(class_names) if class_names else (class_names_from(self.model.meta.get("names")) or [])
        if names and nc is not None and len(names) != nc:
            raise InputError(names_source if class_names else self.path, f"{len(names)} class names but {self.path.name} has {nc} classes (output {'x'.join(map(str, out))})")
        self.class_names = names or [str(i + 1) for i in range(nc or 0)]

    def classify(self, crops: list[np.ndarray]) -> list[tuple[str, float]]:
        """(label, probability) per BGR crop."""
        import cv2

        if not crops:
            return []
        h, w = self.model.input_size
        x = to_tensor([cv2.resize(c, (w, h), interpolation=cv2.INTER_AREA) for c in crops], self.model.channels)
        probs = np.concatenate([outs[0][:n] for n, outs in self.model.run_batch(x)]).astype(np.float32)
        if probs.min() < 0 or probs.max() > 1 or not np.allclose(probs.sum(1), 1, atol=1e-3):  # logits
            e = np.exp(probs - probs.max(1, keepdims=True))
            probs = e / e.sum(1, keepdims=True)
        k = probs.argmax(1)
        return [(self.class_names[i] if i < len(self.class_names) else str(i), float(probs[j, i])) for j, i in enumerate(k)]


def _crop(img: np.ndarray, xyxy, margin: float) -> tuple[np.ndarray | None, tuple[int, int]]:
    h, w = img.shape[:2]
    x1, y1, x2, y2 = [float(v) for v in xyxy]
    mx, my = (x2 - x1) * margin, (y2 - y1) * margin
    a, b = int(max(np.floor(x1 - mx), 0)), int(max(np.floor(y1 - my), 0))
    c, d = int(min(np.ceil(x2 + mx) + 1, w)), int(min(np.ceil(y2 + my) + 1, h))
    if c - a < 2 or d - b < 2:
        return None, (a, b)
    return img[b:d, a:c], (a, b)


class Recogniser:
    """Robot detector, then optional armour detector on robot crops and number classifier on armour crops.
    ``recogniser(image) -> [Detection]``; ``recogniser([images]) -> [[Detection], ...]``. ``last_timings_ms``: robot /
    armour / number stage times (crop + preprocess + inference + decode) of the last call."""

    def __init__(self, robot: OnnxDetector, armour: OnnxDetector | None = None, number: NumberClassifier | None = None, crop_margin: float = 0.05,
                 number_conf: float = 0.5):  # fmt: skip
        self.robot, self.armour, self.number = robot, armour, number
        self.crop_margin = crop_margin
        self.number_conf = number_conf
        self.far = None  # radarcal.runtime.far_windows.FarWindows: native-resolution windows around far robots
        self.last_timings_ms: dict[str, float] = {}

    def __call__(self, images, cameras: list[str] | None = None):
        if isinstance(images, np.ndarray) and (images.ndim == 2 or (images.ndim == 3 and images.shape[2] in (1, 3, 4))):
            return self.detect_batch([images])[0]
        return self.detect_batch(list(images), cameras)

    def detect_batch(self, images: list[np.ndarray], cameras: list[str] | None = None) -> list[list[Detection]]:
        """Per image its detections; ``cameras``: each image's camera (the far-robot windows; None: the primary)."""
        t0 = time.perf_counter()
        robots = self.robot.detect_batch(images)
        t1 = time.perf_counter()
        timings = {"robot": (t1 - t0) * 1e3}
        if self.far is not None:  # robot boxes of the windows merged in before the armour / number stages read them
            robots = self.far.detect(self.robot, images, robots, cameras)
            t0, t1 = t1, time.perf_counter()
            timings["regions"] = (t1 - t0) * 1e3
        if self.armour is not None:
            owners, crops, origins = [], [], []
            for i, (img, dets) in enumerate(zip(images, robots)):
                for j, d in enumerate(dets):
                    crop, org = _crop(img, d.xyxy, self.crop_margin)
                    if crop is not None:
                        owners.append((i, j))
                        crops.append(crop)
                        origins.append(org)
            found = self.armour.detect_batch(crops) if crops else []
            best = {}
            for (i, j), org, arm in zip(owners, origins, found):
                if arm:
                    a = max(arm, key=lambda x: x.score)
                    best[(i, j)] = (a.label, a.xyxy + np.array([org[0], org[1], org[0], org[1]], float))
            t2 = time.perf_counter()
            timings["armour"] = (t2 - t1) * 1e3
            numbers = {}
            if self.number is not None and best:
                keys = list(best)
                ncrops, nkeys = [], []
                for key in keys:
                    crop, _ = _crop(images[key[0]], best[key][1], 0.0)
                    if crop is not None:
                        ncrops.append(crop)
                        nkeys.append(key)
                for key, (lab, p) in zip(nkeys, self.number.classify(ncrops)):
                    if p >= self.number_conf:
                        numbers[key] = lab
                timings["number"] = (time.perf_counter() - t2) * 1e3
            for (i, j), (alabel, axyxy) in best.items():
                d = robots[i][j]
                d.armour_label, d.armour_xyxy = alabel, axyxy
                d.number_label = numbers.get((i, j))
                d.label, d.dead = combine_label(d.label, alabel, d.number_label)
        elif self.number is not None:  # no armour stage: the number classifier reads the robot crops (HUST 2025 style)
            keys, crops = [], []
            for i, (img, dets) in enumerate(zip(images, robots)):
                for j, d in enumerate(dets):
                    crop, _ = _crop(img, d.xyxy, 0.0)
                    if crop is not None:
                        keys.append((i, j))
                        crops.append(crop)
            for (i, j), (lab, p) in zip(keys, self.number.classify(crops)):
                if p >= self.number_conf:
                    d = robots[i][j]
                    d.number_label = lab
                    d.label, d.dead = combine_label(d.label, None, lab)
            timings["number"] = (time.perf_counter() - t1) * 1e3
        self.last_timings_ms = timings
        return robots


class FrameDetector:
    """``detect(frame) -> [Detection]`` for the loop (``frame.load()`` gives the BGR image), exposing the stages'
    ``last_timings_ms``."""

    def __init__(self, recogniser: Recogniser):
        self.recogniser = recogniser

    def __call__(self, frame) -> list[Detection]:
        return self.recogniser(frame.load())

    @property
    def last_timings_ms(self) -> dict[str, float]:
        return self.recogniser.last_timings_ms


class DetectAhead:
    """Pipelined detection: ``frames(src)`` runs the recogniser on each frame in a worker thread as soon as it
    arrives, one frame ahead of the loop, so the networks of frame k+1 run while the loop fuses, tracks and writes
    frame k (onnxruntime releases the GIL). ``detect(frame)`` then returns that frame's result (an unreadable image
    re-raises its InputError there). Throughput becomes max(detector, rest of the loop) instead of their sum, for
    one frame of extra latency. ``workers`` > 1: that many frames are detected at once (each worker its own view of
    the recogniser over the same onnxruntime sessions; give the models one intra-op thread each), for ``workers``
    frames of latency: on 2 cores the most frames per second (measured in docs/runtime.md). ``last_timings_ms``:
    the stage times measured in the worker for the frame returned."""

    def __init__(self, recogniser: Recogniser, depth: int = 1, workers: int = 1):
        import threading

        self.recogniser = recogniser
        self.workers = max(int(workers), 1)
        self.depth = max(int(depth), self.workers)
        self._ready: dict[int, object] = {}
        self._last: dict[str, float] = {}
        self._tls = threading.local()

    def prepare_ahead(self, image):
        """The robot detector's letterbox of ``image`` now (call it in the frame-prefetch thread): its detect call
        then skips that work (:meth:`OnnxDetector.prepare_ahead`)."""
        robot = getattr(self.recogniser, "robot", None)
        return robot.prepare_ahead(image) if hasattr(robot, "prepare_ahead") else image

    def _own(self):
        """This worker thread's recogniser: a shallow copy (own ``last_timings_ms``), sessions shared."""
        if self.workers == 1:
            return self.recogniser
        rec = getattr(self._tls, "rec", None)
        if rec is None:
            import copy

            rec = copy.copy(self.recogniser)
            for k in ("robot", "armour", "number"):
                if getattr(rec, k, None) is not None:
                    setattr(rec, k, copy.copy(getattr(rec, k)))
            self._tls.rec = rec
        return rec

    def _run(self, frame):
        rec = self._own()
        dets = rec(frame.load())
        return dets, dict(rec.last_timings_ms)

    def frames(self, frames):
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        pending: deque = deque()
        with ThreadPoolExecutor(self.workers, thread_name_prefix="radarcal-detect") as ex:
            try:
                for f in frames:
                    pending.append((f, ex.submit(self._run, f)))
                    while len(pending) > self.depth:
                        f0, fut = pending.popleft()
                        self._ready[id(f0)] = fut
                        yield f0
                while pending:
                    f0, fut = pending.popleft()
                    self._ready[id(f0)] = fut
                    yield f0
            finally:
                for _, fut in pending:
                    fut.cancel()
                self._ready.clear()
                if hasattr(frames, "close"):  # stop the source's own threads (frame prefetch) too
                    frames.close()

    def __call__(self, frame) -> list[Detection]:
        fut = self._ready.pop(id(frame), None)
        if fut is None:
            dets, self._last = self._run(frame)
            return dets
        dets, self._last = fut.result()
        return dets

    @property
    def last_timings_ms(self) -> dict[str, float]:
        return self._last

"""Robot detection: a YOLOv5-style ONNX model through onnxruntime, or precomputed boxes from a JSON-lines file.

YOLOv5 export convention (``export.py --include onnx``): input ``images`` 1x3xSxS float32 RGB in 0..1 after a
letterbox (aspect kept, grey 114 padding centred); output 1xNx(5+C) with rows ``cx cy w h objectness cls_1..cls_C``
in letterboxed pixels, already sigmoid-activated; class names in the model metadata ``names`` (a Python dict
literal ``{0: 'red_1', ...}``). Score = objectness x class probability.
"""

from __future__ import annotations

import ast
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radarcal.errors import InputError

__all__ = ["Detection", "letterbox", "decode_yolov5", "nms", "OnnxDetector", "DetectionsFile", "read_class_names"]


@dataclass
class Detection:
    xyxy: np.ndarray  # (4,) image pixels
    label: str
    score: float
    class_id: int = -1

    def to_dict(self) -> dict:
        return {"xyxy": [round(float(v), 2) for v in self.xyxy], "label": self.label, "score": round(float(self.score), 4)}


def letterbox(img: np.ndarray, size: int | tuple[int, int] = 640, color: int = 114) -> tuple[np.ndarray, float, tuple[float, float]]:
    """Resize keeping the aspect ratio and pad to ``size`` (h, w). Returns (image, scale, (pad_x, pad_y)):
    a letterboxed pixel ``p`` maps back to ``(p - pad) / scale`` in the original image."""
    import cv2

    th, tw = (size, size) if isinstance(size, int) else size
    h, w = img.shape[:2]
    r = min(th / h, tw / w)
    nw, nh = int(round(w * r)), int(round(h * r))
    dw, dh = (tw - nw) / 2.0, (th - nh) / 2.0
    if (nw, nh) != (w, h):
        img = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_LINEAR)
    top, bottom = int(round(dh - 0.1)), int(round(dh + 0.1))
    left, right = int(round(dw - 0.1)), int(round(dw + 0.1))
    out = cv2.copyMakeBorder(img, top, bottom, left, right, cv2.BORDER_CONSTANT, value=(color, color, color))
    return out, r, (float(left), float(top))


def nms(boxes: np.ndarray, scores: np.ndarray, iou_thres: float) -> np.ndarray:
    """Greedy NMS over (N,4) xyxy boxes; indices kept, highest score first (IoU vectorised per kept box)."""
    order = np.argsort(-scores, kind="stable")
    x1, y1, x2, y2 = boxes.T
    area = np.maximum(x2 - x1, 0) * np.maximum(y2 - y1, 0)
    keep = []
    while order.size:
        i = order[0]
        keep.append(i)
        rest = order[1:]
        iw = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        ih = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = iw * ih
        iou = inter / np.maximum(area[i] + area[rest] - inter, 1e-12)
        order = rest[iou <= iou_thres]
    return np.asarray(keep, dtype=np.int64)


def decode_yolov5(pred: np.ndarray, conf_thres: float = 0.25, iou_thres: float = 0.45, max_det: int = 300) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 5+C) or (1, N, 5+C) raw YOLOv5 rows -> (boxes xyxy (K,4), scores (K,), class ids (K,)) after the
    confidence filter and class-aware NMS (boxes of different classes never suppress each other)."""
    pred = np.asarray(pred, dtype=np.float32)
    if pred.ndim == 3:
        pred = pred[0]
    if pred.ndim != 2 or pred.shape[1] < 6:
        raise ValueError(f"expected a (N, 5+C) YOLOv5 output, got {pred.shape}")
    pred = pred[pred[:, 4] > conf_thres]
    if not len(pred):
        return np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64)
    cls_scores = pred[:, 5:] * pred[:, 4:5]
    cls = np.argmax(cls_scores, axis=1)
    score = cls_scores[np.arange(len(pred)), cls]
    ok = score > conf_thres
    pred, cls, score = pred[ok], cls[ok], score[ok]
    cx, cy, w, h = pred[:, 0], pred[:, 1], pred[:, 2], pred[:, 3]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    offset = cls[:, None].astype(np.float32) * 8192.0  # class-aware NMS: shift each class to its own region
    keep = nms(boxes + offset, score, iou_thres)[:max_det]
    return boxes[keep], score[keep], cls[keep]


def read_class_names(path: str | os.PathLike) -> list[str]:
    """Class names from a text file (one per line), JSON/YAML list, or a ``{id: name}`` mapping."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(path, f"cannot read class names ({e.__class__.__name__})") from None
    if path.suffix.lower() in (".json", ".yaml", ".yml"):
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError:
            raise InputError(path, "class names: not valid YAML/JSON") from None
        if isinstance(data, dict) and "names" in data:
            data = data["names"]
        names = _names_from(data)
        if names is None:
            raise InputError(path, "class names: expected a list or an {id: name} mapping")
        return names
    names = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not names:
        raise InputError(path, "class names file is empty")
    return names


def _names_from(data) -> list[str] | None:
    if isinstance(data, (list, tuple)):
        return [str(v) for v in data]
    if isinstance(data, dict):
        try:
            return [str(data[k]) for k in sorted(data, key=int)]
        except (TypeError, ValueError):
            return None
    return None


class OnnxDetector:
    """YOLOv5-style ONNX detector. ``threads`` sets onnxruntime's intra-op threads; ``spin`` lets them busy-wait
    (slightly lower latency on a dedicated machine, wasted CPU on a shared one)."""

    def __init__(self, model_path: str | os.PathLike, class_names: list[str] | None = None, conf_thres: float = 0.25, iou_thres: float = 0.45, threads: int = 0, spin: bool = False):
        import onnxruntime as ort

        self.path = Path(model_path)
        if not self.path.is_file():
            raise InputError(self.path, "ONNX model not found")
        so = ort.SessionOptions()
        if threads:
            so.intra_op_num_threads = int(threads)
        so.log_severity_level = 3
        if not spin:  # idle worker threads sleep instead of spinning: no CPU stolen from the rest of the loop / machine
            so.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(self.path), so, providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 - onnxruntime raises its own exception types
            raise InputError(self.path, f"cannot load ONNX model ({str(e).splitlines()[0][:120]})") from None
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = inp.shape
        h = shape[2] if isinstance(shape[2], int) else 640
        w = shape[3] if isinstance(shape[3], int) else 640
        self.input_size = (int(h), int(w))
        out = self.session.get_outputs()[0]
        self.output_name = out.name
        meta = self.session.get_modelmeta().custom_metadata_map
        names = class_names
        if names is None and "names" in meta:
            try:
                names = _names_from(ast.literal_eval(meta["names"]))
            except (ValueError, SyntaxError):
                try:
                    names = _names_from(json.loads(meta["names"]))
                except ValueError:
                    names = None
        self.class_names = list(names) if names else []
        if not self.class_names and isinstance(out.shape[-1], int):
            self.class_names = [f"class_{i}" for i in range(int(out.shape[-1]) - 5)]
        self.conf_thres = conf_thres
        self.iou_thres = iou_thres

    def preprocess(self, img_bgr: np.ndarray) -> tuple[np.ndarray, float, tuple[float, float]]:
        lb, r, pad = letterbox(img_bgr, self.input_size)
        x = lb[:, :, ::-1].transpose(2, 0, 1)[None].astype(np.float32) * (1.0 / 255.0)
        return np.ascontiguousarray(x), r, pad

    def __call__(self, img_bgr: np.ndarray) -> list[Detection]:
        x, r, pad = self.preprocess(img_bgr)
        pred = self.session.run([self.output_name], {self.input_name: x})[0]
        return self.postprocess(pred, r, pad, img_bgr.shape[:2])

    def postprocess(self, pred: np.ndarray, r: float, pad: tuple[float, float], hw: tuple[int, int]) -> list[Detection]:
        boxes, scores, cls = decode_yolov5(pred, self.conf_thres, self.iou_thres)
        boxes = (boxes - np.array([pad[0], pad[1], pad[0], pad[1]], np.float32)) / r
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, hw[1] - 1)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, hw[0] - 1)
        out = []
        for b, s, c in zip(boxes, scores, cls):
            label = self.class_names[c] if c < len(self.class_names) else f"class_{c}"
            out.append(Detection(b.astype(np.float64), label, float(s), int(c)))
        return out


@dataclass
class DetectionsFile:
    """Precomputed detections: one JSON line per frame ``{"t", "frame"?, "boxes": [{"xyxy", "label", "score"}]}``.

    Lookup by frame name when given, else by the nearest time within ``tol`` seconds."""

    times: np.ndarray
    boxes: list[list[Detection]]
    by_frame: dict[str, int] = field(default_factory=dict)
    tol: float = 0.02

    @classmethod
    def read(cls, path: str | os.PathLike, tol: float = 0.02) -> "DetectionsFile":
        path = Path(path)
        if not path.is_file():
            raise InputError(path, "detections file not found")
        times, boxes, by_frame = [], [], {}
        with open(path, encoding="utf-8") as f:
            for i, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    d = json.loads(line)
                    t = float(d["t"])
                    dets = [Detection(np.asarray(b["xyxy"], float).reshape(4), str(b.get("label", "")), float(b.get("score", 1.0))) for b in d.get("boxes", [])]
                except (ValueError, KeyError, TypeError) as e:
                    raise InputError(path, f"line {i}: not a detection record ({e.__class__.__name__}: {e})") from None
                if "frame" in d:
                    by_frame[str(d["frame"])] = len(times)
                times.append(t)
                boxes.append(dets)
        order = np.argsort(times, kind="stable")
        remap = {int(o): k for k, o in enumerate(order)}
        return cls(np.asarray(times, float)[order], [boxes[o] for o in order], {k: remap[v] for k, v in by_frame.items()}, tol)

    def lookup(self, t: float, frame: str | None = None) -> list[Detection]:
        if frame is not None and frame in self.by_frame:
            return self.boxes[self.by_frame[frame]]
        if not len(self.times):
            return []
        i = int(np.searchsorted(self.times, t))
        cand = [j for j in (i - 1, i) if 0 <= j < len(self.times)]
        j = min(cand, key=lambda k: abs(self.times[k] - t))
        return self.boxes[j] if abs(self.times[j] - t) <= self.tol else []

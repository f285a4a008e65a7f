"""Output layouts of the YOLO ONNX exports teams use, recognised from the graph's shapes and metadata, and their decode.

All decoders are pure numpy: raw output arrays of one batch in, per image ``(boxes xyxy (K,4), scores (K,), class ids
(K,))`` in *network input* pixels (letterboxed) out. Layouts:

- ``yolov5``: one output ``B x N x (5+C)``, rows ``cx cy w h obj cls..`` (sigmoid applied); score = obj x cls.
  Also YOLOv7 and other YOLOv5-style exports.
- ``yolov8``: one output ``B x (4+C) x N`` (ultralytics YOLOv8 / YOLO11 / YOLOv12 and later, no objectness), or its
  transpose ``B x N x (4+C)``; score = max class probability.
- ``end2end``: NMS inside the graph. One output ``B x K x 6`` (``x1 y1 x2 y2 score class``: ultralytics
  ``nms=True``, YOLOv10, YOLO26), one output ``M x 7`` (``batch x1 y1 x2 y2 class score``: YOLOv7 ``--end2end`` for
  onnxruntime), or separate outputs: ``num_dets B x 1``, ``boxes B x K x 4``, ``scores B x K``, ``classes B x K``
  (TensorRT EfficientNMS style) / ``dets B x K x 5`` + ``labels B x K`` (mmdetection).
- ``raw``: the per-stride heads before the Detect layer's decode, ``B x 3 x H x W x (5+C)`` (or ``B x 3(5+C) x H x W``)
  logits; anchors (pixels) and strides from a config (YOLOv5 model YAML ``anchors:``), YOLOv5's P3-P5 defaults
  otherwise; decoded as YOLOv5 does (``xy = (2 sig - 0.5 + cell) stride``, ``wh = (2 sig)^2 anchor``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Layout", "LAYOUT_NAMES", "detect_layout", "decode_batch", "nms", "class_aware_nms", "DEFAULT_ANCHORS",
           "read_anchor_config", "UnknownLayout"]  # fmt: skip

# YOLOv5 P3/P4/P5 default anchors (w, h in input pixels) for strides 8, 16, 32
DEFAULT_ANCHORS = [[(10, 13), (16, 30), (33, 23)], [(30, 61), (62, 45), (59, 119)], [(116, 90), (156, 198), (373, 326)]]
LAYOUT_NAMES = {"yolov5": "yolov5", "v5": "yolov5", "yolov7": "yolov5", "yolov8": "yolov8", "v8": "yolov8", "yolo11": "yolov8", "yolov11": "yolov8",
                "yolo12": "yolov8", "yolov12": "yolov8", "end2end": "end2end", "e2e": "end2end", "nms": "end2end", "yolov10": "end2end",
                "yolo26": "end2end", "raw": "raw", "heads": "raw"}  # fmt: skip
_E2E_MAX_K = 1000  # an end-to-end graph keeps at most this many boxes; YOLOv5/v8 heads have thousands of rows


class UnknownLayout(ValueError):
    """The graph's outputs fit no known layout (the message names input and output shapes)."""


@dataclass
class Layout:
    """How to read a detector's outputs. ``nc`` is the class count the output implies (None when it does not say)."""

    name: str  # yolov5 | yolov8 | end2end | raw
    nc: int | None
    variant: str = ""  # yolov8: "" | "transposed"; end2end: "rows6" | "rows7" | "split" | "dets_labels"
    roles: dict[str, int] = field(default_factory=dict)  # end2end split: role -> output index
    anchors: list | None = None  # raw: per level [(w, h)] * 3, levels sorted by stride
    strides: list | None = None
    sigmoid: bool = True  # raw: heads are logits


def _fmt(shape) -> str:
    return "x".join(str(d) if isinstance(d, int) else (str(d) if d else "?") for d in shape)


def describe(inputs, outputs) -> str:
    ins = ", ".join(f"{n} {_fmt(s)}" for n, s in inputs)
    outs = ", ".join(f"{n} {_fmt(s)}" for n, s in outputs)
    return f"input {ins}; output {outs}"


def _int(d) -> int | None:
    return int(d) if isinstance(d, (int, np.integer)) and d > 0 else None


def _is_ultralytics_v8plus(meta: dict) -> bool:
    if "ultralytics" not in str(meta.get("author", "")).lower():
        return False
    try:
        return int(str(meta.get("version", "8")).split(".")[0]) >= 8
    except ValueError:
        return True


def read_anchor_config(data: dict | None) -> tuple[list | None, list | None, bool]:
    """(anchors per level [(w,h),...], strides, sigmoid) from a config mapping (YOLOv5 model YAML style:
    ``anchors: [[10,13, 16,30, 33,23], ...]``, optional ``strides: [8, 16, 32]``, ``sigmoid: false``)."""
    if not data:
        return None, None, True
    anchors = data.get("anchors")
    if anchors is not None:
        anchors = [[(float(a[i]), float(a[i + 1])) for i in range(0, len(a), 2)] if not isinstance(a[0], (list, tuple)) else [tuple(map(float, p)) for p in a]
                   for a in anchors]  # fmt: skip
    strides = [int(s) for s in data["strides"]] if data.get("strides") else None
    return anchors, strides, bool(data.get("sigmoid", True))


def detect_layout(inputs: list[tuple[str, list]], outputs: list[tuple[str, list]], meta: dict, nc_hint: int | None = None,
                  forced: str | None = None) -> Layout:  # fmt: skip
    """The layout of a detector from its input/output (name, shape) lists and metadata. ``nc_hint``: the class count
    the names say (disambiguates ``N x (5+C)`` from ``N x (4+C)``); ``forced``: a name from :data:`LAYOUT_NAMES`.
    Raises :class:`UnknownLayout` naming the shapes."""
    want = LAYOUT_NAMES.get(forced.lower()) if forced else None
    if forced and want is None:
        raise UnknownLayout(f"unknown --detector-layout {forced!r} (one of {', '.join(sorted(set(LAYOUT_NAMES.values())))})")
    e2e_meta = str(meta.get("end2end", meta.get("nms", ""))).lower() == "true"
    shapes = [list(s) for _, s in outputs]
    names = [n.lower() for n, _ in outputs]
    what = describe(inputs, outputs)

    def fail(why: str = "") -> UnknownLayout:
        hint = f" as {want}" if want else ""
        return UnknownLayout(f"cannot read the outputs{hint}{': ' + why if why else ''} ({what}); give --detector-layout yolov5|yolov8|end2end|raw")

    # --- several outputs: raw heads or split end-to-end
    if len(outputs) > 1:
        heads = _raw_heads(shapes)
        if heads is not None and want in (None, "raw"):
            return Layout("raw", heads, anchors=None, strides=None)
        split = _split_roles(names, shapes)
        if split is not None and want in (None, "end2end"):
            variant, roles = split
            return Layout("end2end", None, variant, roles)
        raise fail("several outputs that are neither per-stride heads nor boxes/scores/classes")
    shape = shapes[0]
    if want == "raw":
        heads = _raw_heads(shapes)
        if heads is None:
            raise fail("not B x 3 x H x W x (5+C) heads")
        return Layout("raw", heads)
    if len(shape) == 2 and _int(shape[1]) == 7 and want in (None, "end2end"):
        return Layout("end2end", None, "rows7")
    if len(shape) != 3:
        raise fail(f"output rank {len(shape)}")
    a, k = _int(shape[1]), _int(shape[2])
    if k == 6 and want == "end2end" or (k == 6 and want is None and (e2e_meta or (a is not None and a <= _E2E_MAX_K) or (a is None and nc_hint != 1))):
        return Layout("end2end", None, "rows6")
    if want == "end2end":
        raise fail("not B x K x 6")
    if a is None and k is None:
        raise fail("output dimensions unknown")
    if want is None and nc_hint is not None:  # the names' class count says which one fits
        v5, v8, v8t = k == 5 + nc_hint, a == 4 + nc_hint, k == 4 + nc_hint
        if v5 and not v8:
            return Layout("yolov5", nc_hint)
        if v8 and not v5:
            return Layout("yolov8", nc_hint)
        if v8t and not v8:
            return Layout("yolov8", nc_hint, "transposed")
    channel_first = a is not None and (k is None or a < k)  # (4+C) x N: few rows, many columns (YOLOv5 never is)
    if want == "yolov8" or (want is None and channel_first):
        nc = (a if channel_first else k) - 4
        if nc < 1:
            raise fail("fewer than 5 channels")
        return Layout("yolov8", nc, "" if channel_first else "transposed")
    if channel_first or k is None:
        raise fail("not N x (5+C) rows")
    if want is None and (_is_ultralytics_v8plus(meta) or (nc_hint is not None and k == 4 + nc_hint)):
        return Layout("yolov8", k - 4, "transposed")
    if k < 6:
        raise fail("fewer than 6 values per row")
    return Layout("yolov5", k - 5)


def _raw_heads(shapes) -> int | None:
    """Class count when every output is a per-stride head (B x 3 x H x W x K or B x 3K x H x W) with one K."""
    ks = set()
    for s in shapes:
        if len(s) == 5 and _int(s[1]) == 3 and _int(s[4]) and _int(s[4]) >= 6:
            ks.add(int(s[4]))
        elif len(s) == 4 and _int(s[1]) and int(s[1]) % 3 == 0 and int(s[1]) // 3 >= 6 and _int(s[2]) and _int(s[3]):
            ks.add(int(s[1]) // 3)
        else:
            return None
    return ks.pop() - 5 if len(ks) == 1 else None


def _split_roles(names, shapes):
    roles: dict[str, int] = {}
    for i, (n, s) in enumerate(zip(names, shapes)):
        r = len(s)
        if ("num" in n or "count" in n) and r <= 2:
            roles["num"] = i
        elif r == 3 and _int(s[2]) == 5 and ("det" in n or "box" in n):
            roles["dets"] = i
        elif r == 3 and _int(s[2]) == 4:
            roles["boxes"] = i
        elif ("score" in n or "conf" in n) and r in (2, 3):
            roles["scores"] = i
        elif ("class" in n or "label" in n or "cls" in n) and r in (2, 3):
            roles["classes"] = i
    if "dets" in roles and "classes" in roles:
        return "dets_labels", roles
    if {"boxes", "scores", "classes"} <= set(roles):
        return "split", roles
    # unnamed: (B,1) num, (B,K,4) boxes, then two (B,K) outputs in the order scores, classes
    rank2 = [i for i, s in enumerate(shapes) if len(s) == 2 and _int(s[1]) != 1]
    boxes = [i for i, s in enumerate(shapes) if len(s) == 3 and _int(s[2]) == 4]
    if len(boxes) == 1 and len(rank2) == 2:
        num = [i for i, s in enumerate(shapes) if len(s) in (1, 2) and i not in rank2 and i not in boxes]
        return "split", {"boxes": boxes[0], "scores": rank2[0], "classes": rank2[1], **({"num": num[0]} if num else {})}
    return None


# --- NMS ---------------------------------------------------------------------------------------------------------------
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


def class_aware_nms(boxes, scores, cls, iou_thres, max_det):
    """NMS where boxes of different classes never suppress each other (each class shifted to its own region)."""
    if not len(boxes):
        return np.zeros(0, np.int64)
    offset = cls[:, None].astype(np.float32) * (float(np.abs(boxes).max()) + 1.0) * 2.0
    return nms(boxes + offset, scores, iou_thres)[:max_det]


_EMPTY = (np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64))


def _cxcywh(p):
    cx, cy, w, h = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)


def decode_v5_rows(pred: np.ndarray, conf: float, iou: float, max_det: int = 300):
    """(N, 5+C) YOLOv5 rows -> boxes, scores, classes after the confidence filter and class-aware NMS."""
    pred = pred[pred[:, 4] > conf]
    if not len(pred):
        return _EMPTY
    cls_scores = pred[:, 5:] * pred[:, 4:5]
    cls = np.argmax(cls_scores, axis=1)
    score = cls_scores[np.arange(len(pred)), cls]
    ok = score > conf
    pred, cls, score = pred[ok], cls[ok], score[ok]
    boxes = _cxcywh(pred)
    keep = class_aware_nms(boxes, score, cls, iou, max_det)
    return boxes[keep], score[keep], cls[keep]


def decode_v8_rows(pred: np.ndarray, conf: float, iou: float, max_det: int = 300):
    """(N, 4+C) rows ``cx cy w h cls..`` (no objectness) -> boxes, scores, classes."""
    if pred.shape[1] < 5:
        return _EMPTY
    cls_scores = pred[:, 4:]
    score = cls_scores.max(axis=1)
    ok = score > conf
    if not ok.any():
        return _EMPTY
    pred, score = pred[ok], score[ok]
    cls = np.argmax(pred[:, 4:], axis=1)
    boxes = _cxcywh(pred)
    keep = class_aware_nms(boxes, score, cls, iou, max_det)
    return boxes[keep], score[keep], cls[keep]


def _e2e_filter(boxes, scores, cls, conf, input_hw):
    ok = np.isfinite(scores) & (scores > conf)
    boxes, scores, cls = boxes[ok].astype(np.float32), scores[ok].astype(np.float32), np.rint(cls[ok]).astype(np.int64)
    if len(boxes) and float(np.abs(boxes).max()) <= 1.01 and max(input_hw) > 4:  # normalised 0..1 coordinates
        boxes = boxes * np.array([input_hw[1], input_hw[0], input_hw[1], input_hw[0]], np.float32)
    return boxes, scores, cls


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.clip(x, -60, 60)))


def _raw_to_rows(heads: list[np.ndarray], layout: Layout, input_hw) -> np.ndarray:
    """Per-stride heads (B,3,H,W,K) or (B,3K,H,W) -> (B, N, K) YOLOv5 rows in input pixels."""
    hs = []
    for h in heads:
        if h.ndim == 4:
            b, c, gh, gw = h.shape
            h = h.reshape(b, 3, c // 3, gh, gw).transpose(0, 1, 3, 4, 2)
        hs.append(h)
    hs.sort(key=lambda h: -h.shape[2])  # finest grid (smallest stride) first
    anchors = layout.anchors or DEFAULT_ANCHORS
    if len(anchors) != len(hs):
        raise ValueError(f"{len(hs)} heads but {len(anchors)} anchor levels in the config")
    strides = layout.strides or [input_hw[0] / h.shape[2] for h in hs]
    rows = []
    for h, anc, st in zip(hs, anchors, strides):
        b, na, gh, gw, k = h.shape
        y = _sigmoid(h) if layout.sigmoid else h
        gy, gx = np.meshgrid(np.arange(gh, dtype=np.float32), np.arange(gw, dtype=np.float32), indexing="ij")
        a = np.asarray(anc, np.float32).reshape(1, na, 1, 1, 2)
        xy = (y[..., 0:2] * 2.0 - 0.5 + np.stack([gx, gy], -1)[None, None]) * st
        wh = (y[..., 2:4] * 2.0) ** 2 * a
        rows.append(np.concatenate([xy, wh, y[..., 4:]], -1).reshape(b, -1, k))
    return np.concatenate(rows, axis=1)


def decode_batch(outs: list[np.ndarray], layout: Layout, batch: int, input_hw: tuple[int, int], conf: float = 0.25, iou: float = 0.45,
                 max_det: int = 300) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:  # fmt: skip
    """Raw outputs of one run -> per image (boxes xyxy in input pixels, scores, class ids). Raises ValueError when an
    output does not have the layout's shape."""
    res = []
    if layout.name == "raw":
        rows = _raw_to_rows([np.asarray(o, np.float32) for o in outs], layout, input_hw)
        return [decode_v5_rows(rows[i], conf, iou, max_det) for i in range(min(batch, len(rows)))]
    if layout.name == "end2end" and layout.variant in ("split", "dets_labels"):
        r = layout.roles
        if layout.variant == "dets_labels":
            dets = np.asarray(outs[r["dets"]], np.float32)
            boxes_all, scores_all = dets[..., :4], dets[..., 4]
        else:
            boxes_all = np.asarray(outs[r["boxes"]], np.float32)
            scores_all = np.asarray(outs[r["scores"]], np.float32).reshape(boxes_all.shape[:2])
        cls_all = np.asarray(outs[r["classes"]]).reshape(boxes_all.shape[:2])
        num = np.asarray(outs[r["num"]]).reshape(-1) if "num" in r else None
        for i in range(min(batch, len(boxes_all))):
            n = int(num[i]) if num is not None else boxes_all.shape[1]
            res.append(_e2e_filter(boxes_all[i, :n], scores_all[i, :n], cls_all[i, :n], conf, input_hw))
        return res
    out = np.asarray(outs[0], np.float32)
    if layout.name == "end2end" and layout.variant == "rows7":
        if out.ndim != 2 or out.shape[1] != 7:
            raise ValueError(f"expected M x 7 rows, got {out.shape}")
        bid = np.rint(out[:, 0]).astype(np.int64)
        return [_e2e_filter(out[bid == i, 1:5], out[bid == i, 6], out[bid == i, 5], conf, input_hw) for i in range(batch)]
    if out.ndim == 2:
        out = out[None]
    if out.ndim != 3:
        raise ValueError(f"expected a rank-3 output, got {out.shape}")
    for i in range(min(batch, out.shape[0])):
        p = out[i]
        if layout.name == "end2end":
            if p.shape[1] != 6:
                raise ValueError(f"expected K x 6 rows, got {p.shape}")
            res.append(_e2e_filter(p[:, :4], p[:, 4], p[:, 5], conf, input_hw))
        elif layout.name == "yolov8":
            if layout.variant != "transposed":
                p = p.T
            res.append(decode_v8_rows(np.ascontiguousarray(p), conf, iou, max_det))
        else:
            if p.shape[1] < 6:
                raise ValueError(f"expected N x (5+C) rows, got {p.shape}")
            res.append(decode_v5_rows(p, conf, iou, max_det))
    return res

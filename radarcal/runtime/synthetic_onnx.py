"""Generated ONNX graphs for tests and benchmarks (no weights can be downloaded here). Needs the ``onnx`` package.

- :func:`make_fixed_boxes_model`: a YOLOv5-interface graph (``images`` 1x3xSxS -> ``output`` 1xNx(5+C)) whose output
  is a given table of rows; the input still flows through the graph (``+ 0 * mean(images)``) so onnxruntime runs
  it like a real model. Tests put known boxes in and check the decode path end to end.
- :func:`layout_outputs` + :func:`make_fixed_outputs_model`: known boxes written in any export layout (YOLOv5 rows,
  YOLOv8 channel-first or transposed, end-to-end K x 6 / M x 7 / split boxes-scores-classes / dets+labels, raw
  per-stride logit heads) as a graph that emits them, optionally with a dynamic batch dimension.
- :func:`make_colour_armour_model` / :func:`make_grey_level_classifier`: tiny graphs whose output *depends on the
  pixels*: an armour "detector" (one box at a fixed place in its letterboxed input, class red / blue / grey from the
  crop's mean colour) and a number "classifier" (class from the crop's mean grey level). They check that crops are
  cut, letterboxed, batched and mapped back per robot.
- :func:`make_yolov5n_like`: a random-weight conv net with YOLOv5n's size (stride-2 stem, 4 stages 16..256
  channels, three detection heads at strides 8/16/32 with 3 anchors, the YOLOv5 grid/anchor decode) and the same
  output shape (1x25200x(5+C) at 640). For timing only: its boxes mean nothing.
- :func:`make_yolov8n_like`: a random-weight YOLOv8n-sized net (C2f backbone, SPPF, PAN neck, decoupled heads with
  DFL, 1 x (4+C) x 8400 at 640; ~4.4 GMAC, ~3.1 M parameters) and :func:`make_number_classifier` (a 64 px grey CNN,
  ~27 MMAC per crop). For timing only.
"""

from __future__ import annotations

import os

import numpy as np

from radarcal.io.onnx_files import save_onnx

__all__ = ["make_fixed_boxes_model", "make_yolov5n_like", "count_macs", "layout_outputs", "make_fixed_outputs_model", "make_colour_armour_model",
           "make_grey_level_classifier", "make_yolov8n_like", "make_number_classifier", "ultralytics_meta", "make_square_finder"]


def _names_meta(model, names):
    if names:
        entry = model.metadata_props.add()
        entry.key = "names"
        entry.value = repr({i: n for i, n in enumerate(names)})
        entry = model.metadata_props.add()
        entry.key = "stride"
        entry.value = "32"


def make_fixed_boxes_model(path: str | os.PathLike, rows: np.ndarray, input_size: int = 640, names: list[str] | None = None) -> None:
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rows = np.asarray(rows, np.float32)[None]
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["m"], keepdims=0),
        helper.make_node("Mul", ["m", "zero"], ["z"]),
        helper.make_node("Add", ["table", "z"], ["output"]),
    ]
    graph = helper.make_graph(
        nodes,
        "fixed_boxes",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, input_size, input_size])],
        [helper.make_tensor_value_info("output", TensorProto.FLOAT, list(rows.shape))],
        [numpy_helper.from_array(rows, "table"), numpy_helper.from_array(np.zeros((), np.float32), "zero")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _names_meta(model, names)
    onnx.checker.check_model(model)
    save_onnx(model, path)


def _layers(input_size: int, nc: int):
    no = 5 + nc
    # (cin, cout, k, stride) — YOLOv5n widths (x0.25) and a depth close to its conv count
    spec = [(3, 16, 6, 2), (16, 32, 3, 2), (32, 32, 3, 1), (32, 64, 3, 2), (64, 64, 3, 1), (64, 64, 3, 1),
            (64, 128, 3, 2), (128, 128, 3, 1), (128, 128, 3, 1), (128, 256, 3, 2), (256, 256, 3, 1),
            (256, 128, 1, 1), (128, 128, 3, 1), (128, 64, 1, 1), (64, 64, 3, 1)]  # fmt: skip
    return spec, no


def count_macs(input_size: int = 640, nc: int = 80) -> tuple[int, int]:
    """(multiply-accumulates, parameters) of :func:`make_yolov5n_like` (convolutions only)."""
    spec, no = _layers(input_size, nc)
    s = input_size
    macs = params = 0
    for cin, cout, k, st in spec:
        s = s // st
        macs += s * s * cin * cout * k * k
        params += cin * cout * k * k + cout
    for ch, stride in ((64, 8), (128, 16), (256, 32)):
        g = input_size // stride
        macs += g * g * ch * 3 * no
        params += ch * 3 * no + 3 * no
    return macs, params


def make_yolov5n_like(path: str | os.PathLike, nc: int = 12, input_size: int = 640, names: list[str] | None = None, seed: int = 0,
                      dynamic_batch: bool = False) -> None:  # fmt: skip
    """A random-weight YOLOv5n-sized detector (see the module docstring), batch 1 or (``dynamic_batch``, as YOLOv5's
    ``export.py --dynamic`` writes it) any batch. For timing only."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    spec, no = _layers(input_size, nc)
    nodes, inits = [], []

    def conv(x, cin, cout, k, st, name, act=True, bias=0.0):
        w = (rng.standard_normal((cout, cin, k, k)) * np.sqrt(2.0 / (cin * k * k))).astype(np.float32)
        b = np.full(cout, bias, np.float32)
        inits.extend([numpy_helper.from_array(w, name + "_w"), numpy_helper.from_array(b, name + "_b")])
        pad = k // 2
        if k == 6:
            pad = 2
        nodes.append(helper.make_node("Conv", [x, name + "_w", name + "_b"], [name + "_c"], kernel_shape=[k, k], strides=[st, st], pads=[pad] * 4))
        if not act:
            return name + "_c"
        nodes.append(helper.make_node("Sigmoid", [name + "_c"], [name + "_s"]))
        nodes.append(helper.make_node("Mul", [name + "_c", name + "_s"], [name]))  # SiLU
        return name

    x = "images"
    feats = {}
    s = input_size
    for i, (cin, cout, k, st) in enumerate(spec):
        x = conv(x, cin, cout, k, st, f"l{i}")
        s //= st
        if i == 5:
            feats[8] = (x, 64)
        elif i == 8:
            feats[16] = (x, 128)
        elif i == 10:
            feats[32] = (x, 256)
    anchors = {8: [(10, 13), (16, 30), (33, 23)], 16: [(30, 61), (62, 45), (59, 119)], 32: [(116, 90), (156, 198), (373, 326)]}
    outs = []
    for stride, (fx, ch) in feats.items():
        g = input_size // stride
        bias = np.zeros(3 * no, np.float32)
        bias[4::no] = -9.0  # objectness ~ 1e-4: a random-weight net should not flood NMS
        name = f"head{stride}"
        w = (rng.standard_normal((3 * no, ch, 1, 1)) * 0.01).astype(np.float32)
        inits += [numpy_helper.from_array(w, name + "_w"), numpy_helper.from_array(bias, name + "_b")]
        nodes.append(helper.make_node("Conv", [fx, name + "_w", name + "_b"], [name + "_c"], kernel_shape=[1, 1]))
        b0 = -1 if dynamic_batch else 1
        shp = numpy_helper.from_array(np.array([b0, 3, no, g, g], np.int64), name + "_shape")
        flat = numpy_helper.from_array(np.array([b0, 3 * g * g, no], np.int64), name + "_flat")
        yy, xx = np.meshgrid(np.arange(g), np.arange(g), indexing="ij")
        grid = np.stack([xx, yy], -1)[None, None].astype(np.float32) - 0.5  # (1,1,g,g,2)
        anc = np.array(anchors[stride], np.float32).reshape(1, 3, 1, 1, 2)
        inits += [shp, flat, numpy_helper.from_array(grid, name + "_grid"), numpy_helper.from_array(anc * 4.0, name + "_anc"),
                  numpy_helper.from_array(np.array(2.0, np.float32), name + "_two"), numpy_helper.from_array(np.array(float(stride), np.float32), name + "_stride"),
                  numpy_helper.from_array(np.array([2, 2, no - 4], np.int64), name + "_split")]  # fmt: skip
        nodes += [
            helper.make_node("Reshape", [name + "_c", name + "_shape"], [name + "_r"]),
            helper.make_node("Transpose", [name + "_r"], [name + "_t"], perm=[0, 1, 3, 4, 2]),
            helper.make_node("Sigmoid", [name + "_t"], [name + "_sg"]),
            helper.make_node("Split", [name + "_sg", name + "_split"], [name + "_xy", name + "_wh", name + "_conf"], axis=4),
            # xy = (2 sig - 0.5 + grid) * stride  (grid already holds -0.5); wh = (2 sig)^2 * anchor
            helper.make_node("Mul", [name + "_xy", name + "_two"], [name + "_xy2"]),
            helper.make_node("Add", [name + "_xy2", name + "_grid"], [name + "_xy3"]),
            helper.make_node("Mul", [name + "_xy3", name + "_stride"], [name + "_xyo"]),
            helper.make_node("Mul", [name + "_wh", name + "_wh"], [name + "_wh2"]),
            helper.make_node("Mul", [name + "_wh2", name + "_anc"], [name + "_who"]),
            helper.make_node("Concat", [name + "_xyo", name + "_who", name + "_conf"], [name + "_cat"], axis=4),
            helper.make_node("Reshape", [name + "_cat", name + "_flat"], [name + "_out"]),
        ]
        outs.append(name + "_out")
    nodes.append(helper.make_node("Concat", outs, ["output"], axis=1))
    n = sum(3 * (input_size // s) ** 2 for s in (8, 16, 32))
    bdim = "batch" if dynamic_batch else 1
    graph = helper.make_graph(nodes, "yolov5n_like", [helper.make_tensor_value_info("images", TensorProto.FLOAT, [bdim, 3, input_size, input_size])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, [bdim, n, no])], inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _names_meta(model, names or [f"class_{i}" for i in range(nc)])
    onnx.checker.check_model(model)
    save_onnx(model, path)


# --- known boxes in every export layout --------------------------------------------------------------------------------
def _logit(p):
    p = np.clip(np.asarray(p, np.float64), 1e-9, 1 - 1e-9)
    return np.log(p / (1 - p))


def layout_outputs(layout: str, per_image: list[tuple], nc: int, input_size: int = 640, rows: int = 200, anchors=None) -> dict[str, np.ndarray]:
    """Output tensors of ``layout`` for known boxes. ``per_image``: one ``(boxes xyxy (K,4) in input pixels, class ids
    (K,), scores (K,))`` per batch image. Layouts: yolov5, yolov8, yolov8t (transposed), rows6, rows7, split,
    dets_labels, raw (per-stride logit heads at strides 8/16/32 with ``anchors``, YOLOv5's defaults otherwise)."""
    from radarcal.runtime.yolo_layouts import DEFAULT_ANCHORS

    b = len(per_image)
    sets = [(np.asarray(bx, np.float32).reshape(-1, 4), np.asarray(c, np.int64).reshape(-1), np.asarray(s, np.float32).reshape(-1)) for bx, c, s in per_image]
    if layout in ("yolov5", "yolov8", "yolov8t"):
        off = 5 if layout == "yolov5" else 4
        t = np.zeros((b, rows, off + nc), np.float32)
        for i, (bx, c, s) in enumerate(sets):
            k = len(c)
            t[i, :k, 0:4] = np.column_stack([(bx[:, 0] + bx[:, 2]) / 2, (bx[:, 1] + bx[:, 3]) / 2, bx[:, 2] - bx[:, 0], bx[:, 3] - bx[:, 1]])
            if layout == "yolov5":
                t[i, :k, 4] = s
                t[i, np.arange(k), 5 + c] = 1.0
            else:
                t[i, np.arange(k), 4 + c] = s
        return {"output0": t.transpose(0, 2, 1).copy() if layout == "yolov8" else t}
    if layout == "rows6":
        t = np.zeros((b, 300, 6), np.float32)
        for i, (bx, c, s) in enumerate(sets):
            t[i, : len(c)] = np.column_stack([bx, s, c])
        return {"output0": t}
    if layout == "rows7":
        t = [np.column_stack([np.full(len(c), i), bx, c, s]) for i, (bx, c, s) in enumerate(sets)]
        t = np.vstack(t).astype(np.float32) if t else np.zeros((0, 7), np.float32)
        return {"output": t if len(t) else np.zeros((0, 7), np.float32)}
    if layout in ("split", "dets_labels"):
        kk = 100
        boxes = np.zeros((b, kk, 4), np.float32)
        scores = np.zeros((b, kk), np.float32)
        classes = np.zeros((b, kk), np.int64)
        num = np.zeros((b, 1), np.int32)
        for i, (bx, c, s) in enumerate(sets):
            k = len(c)
            boxes[i, :k], scores[i, :k], classes[i, :k], num[i, 0] = bx, s, c, k
        if layout == "split":
            return {"num_dets": num, "det_boxes": boxes, "det_scores": scores, "det_classes": classes.astype(np.int32)}
        return {"dets": np.concatenate([boxes, scores[..., None]], -1), "labels": classes}
    if layout == "raw":
        anchors = anchors or DEFAULT_ANCHORS
        strides = (8, 16, 32)
        heads = [np.full((b, 3, input_size // st, input_size // st, 5 + nc), -20.0, np.float32) for st in strides]
        for i, (bx, c, s) in enumerate(sets):
            for box, ci, si in zip(bx, c, s):
                cx, cy, w, h = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2, box[2] - box[0], box[3] - box[1]
                cost = sorted((abs(np.log(w / aw)) + abs(np.log(h / ah)), lv, a) for lv, lev in enumerate(anchors) for a, (aw, ah) in enumerate(lev))
                for _, lv, a in cost:  # the best-fitting anchor whose cell slot is still free
                    st = strides[lv]
                    gx, gy = int(cx // st), int(cy // st)
                    if heads[lv][i, a, gy, gx, 4] < -10:
                        break
                aw, ah = anchors[lv][a]
                sx, sy = (cx / st - gx + 0.5) / 2, (cy / st - gy + 0.5) / 2
                sw, sh = np.sqrt(w / aw) / 2, np.sqrt(h / ah) / 2
                if not (0 < sw < 1 and 0 < sh < 1):
                    raise ValueError(f"box {w:.0f}x{h:.0f} px cannot be written with anchor {aw}x{ah}")
                heads[lv][i, a, gy, gx, :5] = _logit([sx, sy, sw, sh, si])
                heads[lv][i, a, gy, gx, 5 + ci] = _logit(1 - 1e-6)
        return {f"head{st}": hd for st, hd in zip(strides, heads)}
    raise ValueError(f"unknown layout {layout!r}")


def ultralytics_meta(names, imgsz=640, end2end: bool | None = None) -> dict[str, str]:
    """The metadata ultralytics writes into its ONNX exports (values are ``str()`` of Python objects)."""
    imgsz = [imgsz, imgsz] if isinstance(imgsz, int) else list(imgsz)
    m = {"author": "Ultralytics", "version": "8.3.0", "task": "detect", "stride": "32", "batch": "1", "imgsz": str(imgsz),
         "names": repr({i: n for i, n in enumerate(names)})}  # fmt: skip
    if end2end is not None:
        m["end2end"] = str(end2end)
    return m


def _save(model, path, meta: dict | None):
    import onnx

    for k, v in (meta or {}).items():
        e = model.metadata_props.add()
        e.key, e.value = str(k), str(v)
    onnx.checker.check_model(model)
    save_onnx(model, path)


def make_fixed_outputs_model(path: str | os.PathLike, outputs: dict[str, np.ndarray], input_shape=(1, 3, 640, 640), meta: dict | None = None,
                             dynamic_batch: bool = False, input_name: str = "images") -> None:  # fmt: skip
    """A graph with one image input whose outputs are the given arrays (``+ 0 * mean(input)``, so it runs like a
    model). ``dynamic_batch``: the input's batch is free and every output (leading dim 1) is repeated per image."""
    from onnx import TensorProto, helper, numpy_helper

    nodes = [helper.make_node("ReduceMean", [input_name], ["m"], keepdims=0), helper.make_node("Mul", ["m", "zero"], ["z"])]
    inits = [numpy_helper.from_array(np.zeros((), np.float32), "zero")]
    outs = []
    if dynamic_batch:
        nodes += [helper.make_node("Shape", [input_name], ["ishape"]), helper.make_node("Slice", ["ishape", "s0", "s1"], ["bdim"])]
        inits += [numpy_helper.from_array(np.array([0], np.int64), "s0"), numpy_helper.from_array(np.array([1], np.int64), "s1")]
    for name, arr in outputs.items():
        arr = np.asarray(arr)
        elem = {np.dtype(np.float32): TensorProto.FLOAT, np.dtype(np.int32): TensorProto.INT32, np.dtype(np.int64): TensorProto.INT64}[arr.dtype]
        inits.append(numpy_helper.from_array(arr, name + "_table"))
        src = name + "_table"
        shape = list(arr.shape)
        if dynamic_batch:
            inits.append(numpy_helper.from_array(np.array(arr.shape[1:], np.int64), name + "_rest"))
            nodes += [helper.make_node("Concat", ["bdim", name + "_rest"], [name + "_shape"], axis=0),
                      helper.make_node("Expand", [src, name + "_shape"], [name + "_exp"])]  # fmt: skip
            src = name + "_exp"
            shape = ["batch"] + shape[1:]
        if elem == TensorProto.FLOAT:
            nodes.append(helper.make_node("Add", [src, "z"], [name]))
        else:
            nodes += [helper.make_node("Cast", ["z"], [name + "_zi"], to=elem), helper.make_node("Add", [src, name + "_zi"], [name])]
        outs.append(helper.make_tensor_value_info(name, elem, shape))
    in_shape = list(input_shape)
    if dynamic_batch:
        in_shape[0] = "batch"
    graph = helper.make_graph(nodes, "fixed_outputs", [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, in_shape)], outs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _save(model, path, meta)


def make_colour_armour_model(path: str | os.PathLike, input_size: int = 192, box=(0.35, 0.6, 0.65, 0.8), names=("blue", "red", "grey"),
                             sharpness: float = 40.0, margin: float = 0.05) -> None:  # fmt: skip
    """An armour "detector" in the YOLOv8 layout, dynamic batch: one box at ``box`` (fractions of its letterboxed
    input) whose class comes from the input's mean colour d = mean(R) - mean(B) (0..1 RGB): red
    ``sig(k (d - margin))``, blue ``sig(k (-d - margin))``, grey ``sig(k (margin - |d|))``."""
    from onnx import TensorProto, helper, numpy_helper

    n_cols = 64
    x1, y1, x2, y2 = (np.asarray(box) * input_size).tolist()
    boxes = np.zeros((1, 4, n_cols), np.float32)
    boxes[0, :, 0] = [(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1]
    mask = np.zeros((1, 1, n_cols), np.float32)
    mask[0, 0, 0] = 1.0
    inits = [numpy_helper.from_array(boxes, "boxes"), numpy_helper.from_array(mask, "mask"),
             numpy_helper.from_array(np.array([1, 0, -1], np.float32).reshape(1, 3), "wd"),
             numpy_helper.from_array(np.array(sharpness, np.float32), "k"), numpy_helper.from_array(np.array(margin, np.float32), "mg"),
             numpy_helper.from_array(np.array([-1, 3, 1], np.int64), "s3"), numpy_helper.from_array(np.array([-1, 1, 1], np.int64), "s1")]  # fmt: skip
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["rgb"], axes=[2, 3], keepdims=0),  # (B,3)
        helper.make_node("Mul", ["rgb", "wd"], ["rgbw"]),
        helper.make_node("ReduceSum", ["rgbw", "one"], ["d"], keepdims=1),  # (B,1) R - B
        helper.make_node("Neg", ["d"], ["nd"]),
        helper.make_node("Abs", ["d"], ["ad"]),
        helper.make_node("Sub", ["d", "mg"], ["r0"]), helper.make_node("Sub", ["nd", "mg"], ["b0"]), helper.make_node("Sub", ["mg", "ad"], ["g0"]),
    ]
    inits.append(numpy_helper.from_array(np.array([1], np.int64), "one"))
    cols = {"red": "r0", "blue": "b0", "grey": "g0"}
    parts = []
    for n in names:
        key = "grey" if n.lower() in ("grey", "gray", "dead", "purple") else n.lower()
        parts.append(cols[key])
    nodes += [helper.make_node("Concat", parts, ["cat"], axis=1), helper.make_node("Mul", ["cat", "k"], ["catk"]),
              helper.make_node("Sigmoid", ["catk"], ["probs"]), helper.make_node("Reshape", ["probs", "s3"], ["probs3"]),
              helper.make_node("Mul", ["probs3", "mask"], ["cls"]),  # (B,3,N): the class scores in column 0 only
              helper.make_node("ReduceMean", ["images"], ["m"], axes=[1, 2, 3], keepdims=0), helper.make_node("Reshape", ["m", "s1"], ["m3"]),
              helper.make_node("Mul", ["m3", "zero"], ["z3"]), helper.make_node("Add", ["boxes", "z3"], ["bx"]),  # (B,4,N)
              helper.make_node("Concat", ["bx", "cls"], ["output0"], axis=1)]  # fmt: skip
    inits.append(numpy_helper.from_array(np.zeros((), np.float32), "zero"))
    graph = helper.make_graph(nodes, "colour_armour", [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 3, input_size, input_size])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, ["batch", 4 + len(names), n_cols])], inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    _save(model, path, ultralytics_meta(list(names), input_size))


def make_grey_level_classifier(path: str | os.PathLike, levels, names, input_size: int = 64, channels: int = 1, width: float = 0.04) -> None:
    """A number "classifier", dynamic batch: softmax over classes of ``-((mean grey - level_k) / width)^2`` (grey
    0..1), so a crop painted with grey level ``levels[k]`` is class ``names[k]``. Output B x C probabilities."""
    from onnx import TensorProto, helper, numpy_helper

    lv = np.asarray(levels, np.float32).reshape(1, -1)
    inits = [numpy_helper.from_array(lv, "levels"), numpy_helper.from_array(np.array(-1.0 / width**2, np.float32), "neg")]
    nodes = [helper.make_node("ReduceMean", ["images"], ["m"], axes=[1, 2, 3], keepdims=0), helper.make_node("Unsqueeze", ["m", "ax1"], ["m1"]),
             helper.make_node("Sub", ["m1", "levels"], ["d"]), helper.make_node("Mul", ["d", "d"], ["d2"]), helper.make_node("Mul", ["d2", "neg"], ["lg"]),
             helper.make_node("Softmax", ["lg"], ["output0"], axis=1)]  # fmt: skip
    inits.append(numpy_helper.from_array(np.array([1], np.int64), "ax1"))
    graph = helper.make_graph(nodes, "grey_level", [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", channels, input_size, input_size])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, ["batch", len(names)])], inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    _save(model, path, {"names": repr({i: n for i, n in enumerate(names)}), "task": "classify", "imgsz": str([input_size, input_size])})


# --- random-weight nets of the real sizes (timing) ---------------------------------------------------------------------
class _Net:
    """A tiny ONNX graph builder that counts multiply-accumulates and parameters as it goes."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.nodes, self.inits = [], []
        self.macs = self.params = 0
        self.k = 0

    def name(self, p: str) -> str:
        self.k += 1
        return f"{p}{self.k}"

    def const(self, arr, p="c") -> str:
        n = self.name(p)
        from onnx import numpy_helper

        self.inits.append(numpy_helper.from_array(np.asarray(arr), n))
        return n

    def node(self, op, ins, **kw) -> str:
        from onnx import helper

        out = self.name(op.lower())
        self.nodes.append(helper.make_node(op, ins, [out], **kw))
        return out

    def conv(self, x, cin, cout, k, s, hw, act=True, bias=0.0, scale=1.0) -> tuple[str, int]:
        """Conv (+ SiLU); ``hw``: input side in pixels; returns (tensor, output side)."""
        w = (self.rng.standard_normal((cout, cin, k, k)) * np.sqrt(2.0 / (cin * k * k)) * scale).astype(np.float32)
        b = np.full(cout, bias, np.float32)
        out_hw = hw // s
        self.macs += out_hw * out_hw * cin * cout * k * k
        self.params += w.size + b.size
        y = self.node("Conv", [x, self.const(w, "w"), self.const(b, "b")], kernel_shape=[k, k], strides=[s, s], pads=[k // 2] * 4)
        if act:
            y = self.node("Mul", [y, self.node("Sigmoid", [y])])
        return y, out_hw

    def c2f(self, x, cin, cout, n, hw, shortcut=True) -> str:
        c = cout // 2
        y, _ = self.conv(x, cin, 2 * c, 1, 1, hw)
        from onnx import helper

        a, b = self.name("sa"), self.name("sb")
        self.nodes.append(helper.make_node("Split", [y, self.const(np.array([c, c], np.int64), "sp")], [a, b], axis=1))
        parts = [a, b]
        cur = b
        for _ in range(n):
            t, _ = self.conv(cur, c, c, 3, 1, hw)
            t, _ = self.conv(t, c, c, 3, 1, hw)
            cur = self.node("Add", [cur, t]) if shortcut else t
            parts.append(cur)
        y = self.node("Concat", parts, axis=1)
        out, _ = self.conv(y, (2 + n) * c, cout, 1, 1, hw)
        return out


def make_yolov8n_like(path: str | os.PathLike, nc: int = 12, input_size: int = 640, names: list[str] | None = None, seed: int = 0,
                      dynamic_batch: bool = False) -> dict:  # fmt: skip
    """A random-weight YOLOv8n-sized detector: YOLOv8n's widths (16..256) and C2f depths, SPPF, PAN neck, decoupled
    box (DFL, 16 bins) and class heads, the ultralytics decode inside the graph; output 1 x (4+C) x N
    (N = 8400 at 640) with ultralytics metadata. Returns {"macs", "params"}. For timing only: its boxes mean nothing."""
    from onnx import TensorProto, helper

    g = _Net(seed)
    s = input_size
    x, s = g.conv("images", 3, 16, 3, 2, s)
    x, s = g.conv(x, 16, 32, 3, 2, s)
    x = g.c2f(x, 32, 32, 1, s)
    x, s = g.conv(x, 32, 64, 3, 2, s)
    p3 = g.c2f(x, 64, 64, 2, s)
    x, s = g.conv(p3, 64, 128, 3, 2, s)
    p4 = g.c2f(x, 128, 128, 2, s)
    x, s = g.conv(p4, 128, 256, 3, 2, s)
    x = g.c2f(x, 256, 256, 1, s)
    # SPPF
    y, _ = g.conv(x, 256, 128, 1, 1, s)
    m1 = g.node("MaxPool", [y], kernel_shape=[5, 5], pads=[2] * 4)
    m2 = g.node("MaxPool", [m1], kernel_shape=[5, 5], pads=[2] * 4)
    m3 = g.node("MaxPool", [m2], kernel_shape=[5, 5], pads=[2] * 4)
    p5, _ = g.conv(g.node("Concat", [y, m1, m2, m3], axis=1), 512, 256, 1, 1, s)
    s5, s4, s3 = s, s * 2, s * 4
    up_scale = g.const(np.array([1, 1, 2, 2], np.float32), "up")
    # top-down
    u = g.node("Resize", [p5, "", up_scale], mode="nearest")
    n4 = g.c2f(g.node("Concat", [u, p4], axis=1), 384, 128, 1, s4, shortcut=False)
    u = g.node("Resize", [n4, "", up_scale], mode="nearest")
    o3 = g.c2f(g.node("Concat", [u, p3], axis=1), 192, 64, 1, s3, shortcut=False)
    # bottom-up
    d, _ = g.conv(o3, 64, 64, 3, 2, s3)
    o4 = g.c2f(g.node("Concat", [d, n4], axis=1), 192, 128, 1, s4, shortcut=False)
    d, _ = g.conv(o4, 128, 128, 3, 2, s4)
    o5 = g.c2f(g.node("Concat", [d, p5], axis=1), 384, 256, 1, s5, shortcut=False)
    reg = 16
    boxes, scores = [], []
    proj = g.const(np.arange(reg, dtype=np.float32).reshape(1, 1, reg, 1), "proj")
    for feat, ch, side in ((o3, 64, s3), (o4, 128, s4), (o5, 256, s5)):
        stride = input_size // side
        b, _ = g.conv(feat, ch, 64, 3, 1, side)
        b, _ = g.conv(b, 64, 64, 3, 1, side)
        b, _ = g.conv(b, 64, 4 * reg, 1, 1, side, act=False, scale=0.1)
        c3 = max(min(ch, 64), min(nc, 100))  # YOLOv8n: max(64, nc)
        c, _ = g.conv(feat, ch, c3, 3, 1, side)
        c, _ = g.conv(c, c3, c3, 3, 1, side)
        c, _ = g.conv(c, c3, nc, 1, 1, side, act=False, bias=-9.0, scale=0.1)  # class prob ~1e-4: no NMS flood
        hw = side * side
        # DFL: softmax over the 16 bins of each side, expectation -> distances (cells) -> ltrb -> cx cy w h (pixels)
        bd = g.node("Reshape", [b, g.const(np.array([-1, 4, reg, hw], np.int64), "sh")])
        bd = g.node("Softmax", [bd], axis=2)
        dist = g.node("ReduceSum", [g.node("Mul", [bd, proj]), g.const(np.array([2], np.int64), "ax")], keepdims=0)  # (B,4,hw)
        yy, xx = np.meshgrid(np.arange(side, dtype=np.float32) + 0.5, np.arange(side, dtype=np.float32) + 0.5, indexing="ij")
        anchors = np.stack([xx.ravel(), yy.ravel()])[None]  # (1,2,hw)
        from onnx import helper as _h

        lt, rb = g.name("lt"), g.name("rb")
        g.nodes.append(_h.make_node("Split", [dist, g.const(np.array([2, 2], np.int64), "sp")], [lt, rb], axis=1))
        a = g.const(anchors, "anc")
        x1y1 = g.node("Sub", [a, lt])
        x2y2 = g.node("Add", [a, rb])
        cxy = g.node("Mul", [g.node("Add", [x1y1, x2y2]), g.const(np.array(0.5, np.float32), "half")])
        wh = g.node("Sub", [x2y2, x1y1])
        box = g.node("Mul", [g.node("Concat", [cxy, wh], axis=1), g.const(np.array(float(stride), np.float32), "st")])
        boxes.append(box)
        scores.append(g.node("Sigmoid", [g.node("Reshape", [c, g.const(np.array([-1, nc, hw], np.int64), "sh")])]))
    out = g.node("Concat", [g.node("Concat", boxes, axis=2), g.node("Concat", scores, axis=2)], axis=1)
    g.nodes.append(helper.make_node("Identity", [out], ["output0"]))
    n = sum((input_size // st) ** 2 for st in (8, 16, 32))
    bdim = "batch" if dynamic_batch else 1
    graph = helper.make_graph(g.nodes, "yolov8n_like", [helper.make_tensor_value_info("images", TensorProto.FLOAT, [bdim, 3, input_size, input_size])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [bdim, 4 + nc, n])], g.inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _save(model, path, ultralytics_meta(names or [f"class_{i}" for i in range(nc)], input_size))
    return {"macs": g.macs, "params": g.params}


def make_number_classifier(path: str | os.PathLike, nc: int = 9, input_size: int = 64, names: list[str] | None = None, seed: int = 0) -> dict:
    """A random-weight 64 px grey number classifier (conv 24-48-96-96 with pooling, global average, linear,
    softmax; ~27 MMAC and ~0.14 M parameters per crop, about MobileNetV2's cost at 64 px), dynamic batch.
    Returns {"macs", "params"}. For timing only."""
    from onnx import TensorProto, helper

    g = _Net(seed)
    s = input_size
    x, s = g.conv("images", 1, 24, 3, 1, s)
    x = g.node("MaxPool", [x], kernel_shape=[2, 2], strides=[2, 2])
    s //= 2
    x, s = g.conv(x, 24, 48, 3, 1, s)
    x = g.node("MaxPool", [x], kernel_shape=[2, 2], strides=[2, 2])
    s //= 2
    x, s = g.conv(x, 48, 96, 3, 1, s)
    x = g.node("MaxPool", [x], kernel_shape=[2, 2], strides=[2, 2])
    s //= 2
    x, s = g.conv(x, 96, 96, 3, 1, s)
    x = g.node("GlobalAveragePool", [x])
    x, _ = g.conv(x, 96, nc, 1, 1, 1, act=False)
    x = g.node("Flatten", [x], axis=1)
    g.nodes.append(helper.make_node("Softmax", [x], ["output0"], axis=1))
    graph = helper.make_graph(g.nodes, "number_cls", [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 1, input_size, input_size])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, ["batch", nc])], g.inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _save(model, path, {"names": repr({i: n for i, n in enumerate(names or [str(i + 1) for i in range(nc)])}), "task": "classify",
                        "imgsz": str([input_size, input_size])})  # fmt: skip
    return {"macs": g.macs, "params": g.params}


def make_square_finder(path: str | os.PathLike, side: int = 24, stride: int = 4, input_size: int = 640, names=("red", "blue"), power: int = 4,
                       batch: int | str = "batch") -> None:  # fmt: skip
    """A detector whose boxes come from the pixels, for tiling / region tests: it finds solid red and blue squares of
    ``side`` pixels (at the scale it is fed) and emits them in the YOLOv8 layout (1 x 6 x N, dynamic batch). Per
    class a colour mask (relu(R - G - B), relu(B - R - G); 0..1 RGB) is box-filtered over ``side`` x ``side`` at
    ``stride``; the score is that mean to the ``power``. A square whose top-left pixel (a, b) in the network input
    has a and b multiples of ``stride`` gives score 1 with the box ``[a - 0.5, b - 0.5, a + side - 0.5, b + side -
    0.5]`` exactly (pixel centres at integers); a square shrunk by the letterbox (or cut by a window) scores low.
    ``batch``: ``"batch"`` (dynamic) or a fixed batch size."""
    from onnx import TensorProto, helper, numpy_helper

    k = int(side)
    g = input_size // stride + 1  # conv output side with pads k/2 each side
    w_mask = np.array([[1, -1, -1], [-1, -1, 1]], np.float32).reshape(2, 3, 1, 1)
    w_box = np.full((2, 1, k, k), 1.0 / (k * k), np.float32)
    iy, ix = np.meshgrid(np.arange(g, dtype=np.float32), np.arange(g, dtype=np.float32), indexing="ij")
    boxes = np.stack([ix.ravel() * stride - 0.5, iy.ravel() * stride - 0.5, np.full(g * g, k, np.float32), np.full(g * g, k, np.float32)])[None]
    inits = [numpy_helper.from_array(w_mask, "w_mask"), numpy_helper.from_array(w_box, "w_box"), numpy_helper.from_array(boxes.astype(np.float32), "anchors"),
             numpy_helper.from_array(np.array([0, 2, g * g], np.int64), "flat"), numpy_helper.from_array(np.zeros((), np.float32), "zero")]  # fmt: skip
    nodes = [
        helper.make_node("Conv", ["images", "w_mask"], ["m"], kernel_shape=[1, 1]),
        helper.make_node("Relu", ["m"], ["mr"]),
        helper.make_node("Conv", ["mr", "w_box"], ["r"], kernel_shape=[k, k], strides=[stride, stride], pads=[k // 2] * 4, group=2),
        helper.make_node("Reshape", ["r", "flat"], ["p1"]),
    ]
    cur = "p1"
    for i in range(int(power) - 1):
        nodes.append(helper.make_node("Mul", [cur, "p1"], [f"p{i + 2}"]))
        cur = f"p{i + 2}"
    nodes += [
        helper.make_node("ReduceMax", [cur], ["smax"], axes=[1], keepdims=1),
        helper.make_node("Mul", ["smax", "zero"], ["z"]),
        helper.make_node("Add", ["z", "anchors"], ["bx"]),
        helper.make_node("Concat", ["bx", cur], ["output0"], axis=1),
    ]
    graph = helper.make_graph(nodes, "square_finder", [helper.make_tensor_value_info("images", TensorProto.FLOAT, [batch, 3, input_size, input_size])],
                              [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [batch, 4 + len(names), g * g])], inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _save(model, path, ultralytics_meta(list(names), input_size))

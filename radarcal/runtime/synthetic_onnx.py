"""Generated ONNX graphs for tests and benchmarks (no weights can be downloaded here). Needs the ``onnx`` package.

- :func:`make_fixed_boxes_model`: a YOLOv5-interface graph (``images`` 1x3xSxS -> ``output`` 1xNx(5+C)) whose output
  is a given table of rows; the input still flows through the graph (``+ 0 * mean(images)``) so onnxruntime runs
  it like a real model. Tests put known boxes in and check the decode path end to end.
- :func:`make_yolov5n_like`: a random-weight conv net with YOLOv5n's size (stride-2 stem, 4 stages 16..256
  channels, three detection heads at strides 8/16/32 with 3 anchors, the YOLOv5 grid/anchor decode) and the same
  output shape (1x25200x(5+C) at 640). For timing only: its boxes mean nothing.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["make_fixed_boxes_model", "make_yolov5n_like", "count_macs"]


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
    onnx.save(model, str(path))


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


def make_yolov5n_like(path: str | os.PathLike, nc: int = 12, input_size: int = 640, names: list[str] | None = None, seed: int = 0) -> None:
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
        shp = numpy_helper.from_array(np.array([1, 3, no, g, g], np.int64), name + "_shape")
        flat = numpy_helper.from_array(np.array([1, 3 * g * g, no], np.int64), name + "_flat")
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
    graph = helper.make_graph(nodes, "yolov5n_like", [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, input_size, input_size])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, n, no])], inits)  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    _names_meta(model, names or [f"class_{i}" for i in range(nc)])
    onnx.checker.check_model(model)
    onnx.save(model, str(path))

"""Every export layout decoded end to end through onnxruntime: generated graphs emit known boxes (in letterbox pixels
of non-square frames), the detector must give them back in image pixels, per image of a batch, and nothing for an
empty output."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io.detector_files import read_class_names
from radarcal.runtime.detector import OnnxDetector, letterbox
from radarcal.runtime.synthetic_onnx import layout_outputs, make_fixed_outputs_model, make_yolov8n_like, ultralytics_meta

NAMES = ["red_1", "red_3", "blue_1", "blue_7", "blue_4"]
LAYOUTS = {"yolov5": "yolov5", "yolov8": "yolov8", "yolov8t": "yolov8", "rows6": "end2end", "rows7": "end2end", "split": "end2end",
           "dets_labels": "end2end", "raw": "raw"}  # fmt: skip
# frame sizes of a batch: the station's 1280x1024, a 16:9 frame and a portrait crop (letterbox pads differ per image)
FRAMES = [(1024, 1280), (1080, 1920), (900, 500)]
TRUTH = [  # per frame: (xyxy image pixels, class, score)
    [([100, 200, 300, 400], 0, 0.95), ([900.5, 300.25, 1000.0, 420.0], 3, 0.8), ([120, 210, 310, 405], 2, 0.9)],
    [([1500, 600, 1620, 700], 1, 0.7), ([40, 500, 200, 1000], 4, 0.88)],
    [([50, 100, 450, 300], 0, 0.6)],
]


def _to_input(xyxy, hw, size):
    """Image pixels -> letterbox pixels of a (h, w) frame in a size x size input (the letterbox's own geometry)."""
    _, r, (px, py) = letterbox(np.zeros(hw + (3,), np.uint8), size)
    return np.asarray(xyxy, float) * r + [px, py, px, py]


def _per_image(size):
    out = []
    for hw, dets in zip(FRAMES, TRUTH):
        out.append((np.array([_to_input(b, hw, size) for b, _, _ in dets]), np.array([c for _, c, _ in dets]), np.array([s for _, _, s in dets])))
    return out


def _frames():
    rng = np.random.default_rng(0)
    return [rng.integers(0, 255, hw + (3,), dtype=np.uint8) for hw in FRAMES]


def _model(tmp_path, layout, size=640, per_image=None, meta=None, name="m.onnx"):
    per_image = _per_image(size) if per_image is None else per_image
    outs = layout_outputs(layout, per_image, len(NAMES), size)
    path = tmp_path / f"{layout}_{name}"
    make_fixed_outputs_model(path, outs, (len(per_image), 3, size, size), meta if meta is not None else {"names": repr(dict(enumerate(NAMES)))})
    return path


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_layout_detected_and_decoded_per_image(tmp_path, layout):
    det = OnnxDetector(_model(tmp_path, layout), threads=1)
    assert det.layout.name == LAYOUTS[layout]
    assert det.class_names == NAMES
    out = det(_frames())  # one batched run of three frames of three sizes
    assert len(out) == 3
    if layout == "yolov8":  # fixed batch 3 fed two frames: padded with a blank image, its rows ignored
        assert [len(x) for x in det(_frames()[:2])] == [3, 2]
        mono = [f[:, :, 1].copy() for f in _frames()]  # a mono camera's 2-D frames: same geometry, same boxes
        assert [len(x) for x in det(mono)] == [3, 2, 1] and len(det(mono[0])) == 3
    tol = 0.05 if layout == "raw" else 2e-3  # raw: sigmoid/logit round trip in float32
    for dets, truth in zip(out, TRUTH):
        assert len(dets) == len(truth)
        got = {d.label: d for d in dets}
        for xyxy, c, s in truth:
            d = got[NAMES[c]]
            np.testing.assert_allclose(d.xyxy, xyxy, atol=tol * max(1.0, 1280 / 640 * 2))
            assert d.score == pytest.approx(s, rel=1e-4)


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_empty_outputs_give_no_detections(tmp_path, layout):
    empty = [(np.zeros((0, 4)), np.zeros(0, int), np.zeros(0))] * 2
    det = OnnxDetector(_model(tmp_path, layout, per_image=empty), threads=1)
    assert det(_frames()[:2]) == [[], []]
    assert det([]) == []


def test_forced_layout_and_rectangular_input(tmp_path):
    # a YOLOv8 graph exported at 384x640 (h x w): letterbox to the rectangle, boxes back exactly
    size = (384, 640)
    hw = (1024, 1280)
    _, r, (px, py) = letterbox(np.zeros(hw + (3,), np.uint8), size)
    assert r == 0.375 and px == 80.0 and py == 0.0
    box = np.array([[400, 300, 520, 460]], float)
    lb = box * r + [px, py, px, py]
    outs = layout_outputs("yolov8", [(lb, [1], [0.9])], len(NAMES), 640)
    path = tmp_path / "rect.onnx"
    make_fixed_outputs_model(path, outs, (1, 3, *size), ultralytics_meta(NAMES, list(size)))
    for forced in (None, "yolo11", "yolov8"):
        det = OnnxDetector(path, layout=forced, threads=1)
        assert det.input_size == size and det.layout.name == "yolov8"
        (d,) = det(np.zeros(hw + (3,), np.uint8))
        assert d.label == "red_3"
        np.testing.assert_allclose(d.xyxy, box[0], atol=2e-3)
    # the same table read as YOLOv5 is refused: a channel-first output is not N x (5+C)
    with pytest.raises(InputError, match=r"1x9x200"):
        OnnxDetector(path, layout="yolov5")


def test_transposed_v8_told_from_v5_by_the_names(tmp_path):
    # 200 x 9 rows: YOLOv5 with 4 classes or YOLOv8-transposed with 5; the 5 names decide
    path = _model(tmp_path, "yolov8t", per_image=_per_image(640)[:1], meta={"names": repr(dict(enumerate(NAMES)))})
    assert OnnxDetector(path).layout.name == "yolov8"
    (tmp_path / "four.txt").write_text("a\nb\nc\nd\n")
    det = OnnxDetector(path, class_names=read_class_names(tmp_path / "four.txt"))
    assert det.layout.name == "yolov5" and det.layout.nc == 4


def test_yolov8n_sized_graph(tmp_path):
    stats = make_yolov8n_like(tmp_path / "v8n80.onnx", nc=80, input_size=640)
    # YOLOv8n (COCO, 80 classes): 8.7 GFLOPs = 4.35 GMAC, 3.16 M parameters
    assert 4.0e9 < stats["macs"] < 4.6e9 and 2.9e6 < stats["params"] < 3.4e6
    make_yolov8n_like(tmp_path / "v8n.onnx", nc=12, input_size=320, names=[f"c{i}" for i in range(12)])
    det = OnnxDetector(tmp_path / "v8n.onnx", threads=1)
    assert det.layout.name == "yolov8" and det.layout.nc == 12 and det.input_size == (320, 320)
    out = det.session.run(None, {"images": np.zeros((1, 3, 320, 320), np.float32)})[0]
    assert out.shape == (1, 16, 40 * 40 + 20 * 20 + 10 * 10)
    assert det(np.zeros((512, 640, 3), np.uint8)) == []  # random weights, class bias -9: nothing above 0.25

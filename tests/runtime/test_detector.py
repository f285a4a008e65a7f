"""YOLOv5 decode path run for real through onnxruntime on a generated graph that emits known boxes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.io.detector_files import read_class_names
from radarcal.runtime.detector import DetectionsFile, OnnxDetector, decode_yolov5, letterbox, nms
from radarcal.runtime.synthetic_onnx import count_macs, make_fixed_boxes_model, make_yolov5n_like

NAMES = ["red_1", "red_3", "blue_1", "blue_7"]


def row(xyxy_img, cls, obj, cls_p=0.9, r=0.5, pad=(0.0, 64.0), nc=4):
    """A raw YOLOv5 output row for a box given in ORIGINAL image pixels (1280x1024 -> 640 letterbox)."""
    x1, y1, x2, y2 = np.asarray(xyxy_img, float) * r + [pad[0], pad[1], pad[0], pad[1]]
    out = np.zeros(5 + nc, np.float32)
    out[:5] = [(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1, obj]
    out[5 + cls] = cls_p
    return out


def test_letterbox_geometry():
    img = np.zeros((1024, 1280, 3), np.uint8)
    lb, r, pad = letterbox(img, 640)
    assert lb.shape == (640, 640, 3) and r == 0.5 and pad == (0.0, 64.0)
    assert (lb[:64] == 114).all() and (lb[64:576] == 0).all() and (lb[576:] == 114).all()
    lb, r, pad = letterbox(np.zeros((480, 640, 3), np.uint8), (384, 640))
    assert lb.shape == (384, 640, 3) and r == 0.8 and pad == (64.0, 0.0)


def test_nms_and_class_aware_decode():
    b = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30]], float)
    assert nms(b, np.array([0.9, 0.8, 0.7]), 0.5).tolist() == [0, 2]
    pred = np.array([[5, 5, 10, 10, 0.9, 0.9, 0.0], [5.5, 5.5, 10, 10, 0.9, 0.0, 0.8], [5.2, 5.2, 10, 10, 0.8, 0.9, 0]], np.float32)
    boxes, scores, cls = decode_yolov5(pred, 0.25, 0.45)
    assert sorted(cls.tolist()) == [0, 1]  # the same-class duplicate is suppressed, the other class survives
    np.testing.assert_allclose(sorted(scores.tolist()), [0.72, 0.81], rtol=1e-6)


def test_onnx_detector_returns_known_boxes(tmp_path):
    truth = {"red_1": [100, 200, 300, 400], "blue_7": [900.5, 300.25, 1000.0, 420.0], "blue_1": [120, 210, 310, 405]}
    rows = [
        row(truth["red_1"], 0, 0.95),
        row([104, 204, 302, 398], 0, 0.90),  # same class, IoU ~0.95 -> suppressed
        row(truth["blue_1"], 2, 0.90),  # overlaps red_1 but another class -> kept
        row(truth["blue_7"], 3, 0.8, 0.95),
        row([500, 500, 600, 600], 1, 0.2),  # below the confidence threshold
        row([600, 600, 700, 700], 1, 0.5, 0.3),  # 0.5 * 0.3 = 0.15 < 0.25
    ]
    rows += [np.zeros(9, np.float32)] * 20
    model = tmp_path / "fixed.onnx"
    make_fixed_boxes_model(model, np.stack(rows), 640, NAMES)
    det = OnnxDetector(model, threads=1)
    assert det.class_names == NAMES and det.input_size == (640, 640)
    img = np.random.default_rng(0).integers(0, 255, (1024, 1280, 3), dtype=np.uint8)
    out = {d.label: d for d in det(img)}
    assert set(out) == set(truth)
    for label, box in truth.items():
        np.testing.assert_allclose(out[label].xyxy, box, atol=1e-3)  # back to image pixels exactly
    assert out["red_1"].score == pytest.approx(0.95 * 0.9, rel=1e-6)
    # names from a file override the metadata
    (tmp_path / "names.txt").write_text("a\nb\nc\nd\n")
    det2 = OnnxDetector(model, class_names=read_class_names(tmp_path / "names.txt"))
    assert {d.label for d in det2(img)} == {"a", "c", "d"}
    (tmp_path / "names.yaml").write_text("names: {0: x, 1: y, 2: z, 3: w}\n")
    assert read_class_names(tmp_path / "names.yaml") == ["x", "y", "z", "w"]


def test_bad_model_and_detections_file(tmp_path):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not onnx")
    with pytest.raises(InputError, match="bad.onnx"):
        OnnxDetector(bad)
    p = tmp_path / "d.jsonl"
    p.write_text(json.dumps({"t": 0.1, "frame": "000003.jpg", "boxes": [{"xyxy": [1, 2, 3, 4], "label": "red_1", "score": 0.9}]}) + "\n"
                 + json.dumps({"t": 0.0, "boxes": []}) + "\n")
    df = DetectionsFile.read(p)
    assert df.lookup(0.1)[0].label == "red_1" and df.lookup(0.105)[0].label == "red_1"
    assert df.lookup(0.0) == [] and df.lookup(5.0) == []
    assert df.lookup(99.0, frame="000003.jpg")[0].xyxy.tolist() == [1, 2, 3, 4]
    p.write_text('{"t": 0.1, "boxes": [{"label": "x"}]}\n')
    with pytest.raises(InputError, match="line 1"):
        DetectionsFile.read(p)


def test_yolov5n_sized_graph(tmp_path):
    macs, params = count_macs(640, 80)
    assert 2.0e9 < macs < 2.6e9 and 1.4e6 < params < 2.2e6  # YOLOv5n: 4.5 GFLOPs (~2.25 GMAC), 1.9 M params
    model = tmp_path / "y5n.onnx"
    make_yolov5n_like(model, nc=12, input_size=320)
    det = OnnxDetector(model, threads=1)
    out = det.session.run(None, {"images": np.zeros((1, 3, 320, 320), np.float32)})[0]
    assert out.shape == (1, 3 * (40 * 40 + 20 * 20 + 10 * 10), 17)


def test_class_name_files_in_the_formats_teams_use(tmp_path):
    (tmp_path / "data.yaml").write_text("path: ../datasets/rm\ntrain: images/train\nnc: 3\nnames: ['red_1', 'red_3', 'blue_7']\n")
    assert read_class_names(tmp_path / "data.yaml") == ["red_1", "red_3", "blue_7"]
    (tmp_path / "data2.yaml").write_text("names:\n  0: car\n  1: armor\n")  # ultralytics mapping form
    assert read_class_names(tmp_path / "data2.yaml") == ["car", "armor"]
    (tmp_path / "bad.yaml").write_text("nc: 4\nnames: [a, b]\n")
    with pytest.raises(InputError, match="nc: 4 but 2 names"):
        read_class_names(tmp_path / "bad.yaml")
    (tmp_path / "ids.txt").write_text("# robots\n0 red_1\n1 blue 3\n")
    assert read_class_names(tmp_path / "ids.txt") == ["red_1", "blue 3"]
    (tmp_path / "gap.yaml").write_text("names: {0: a, 2: c}\n")
    with pytest.raises(InputError, match="expected a list"):
        read_class_names(tmp_path / "gap.yaml")
    with pytest.raises(InputError, match="not found"):
        read_class_names(tmp_path / "missing.txt")


def test_providers_resolve_and_fall_back(tmp_path, capsys):
    import onnxruntime as ort

    from radarcal.runtime.detector import resolve_providers

    use, missing = resolve_providers("tensorrt,cuda,cpu")
    assert use[-1] == "CPUExecutionProvider"
    have = set(ort.get_available_providers())
    assert set(missing) == {"TensorrtExecutionProvider", "CUDAExecutionProvider"} - have
    with pytest.raises(InputError, match="unknown provider 'gpu0'"):
        resolve_providers("gpu0")
    model = tmp_path / "m.onnx"
    make_fixed_boxes_model(model, np.stack([row([100, 200, 300, 400], 0, 0.9)]), 640, NAMES)
    det = OnnxDetector(model, providers="cuda")
    assert det.model.providers[-1] == "CPUExecutionProvider" and len(det(np.zeros((1024, 1280, 3), np.uint8))) == 1


def test_raw_heads_with_anchors_from_a_config(tmp_path):
    from radarcal.runtime.synthetic_onnx import layout_outputs, make_fixed_outputs_model

    anchors = [[(8, 8), (12, 20), (20, 12)], [(30, 30), (40, 60), (60, 40)], [(90, 90), (120, 160), (160, 120)]]
    boxes = np.array([[100, 100, 108, 108], [300, 300, 340, 360], [10, 400, 170, 520]], float)
    outs = layout_outputs("raw", [(boxes, [0, 1, 2], [0.9, 0.8, 0.7])], 4, 640, anchors=anchors)
    model = tmp_path / "raw.onnx"
    make_fixed_outputs_model(model, outs, (1, 3, 640, 640), {"names": repr(dict(enumerate(NAMES)))})
    cfg = {"anchors": [[a for wh in lev for a in wh] for lev in anchors], "strides": [8, 16, 32]}  # YOLOv5 YAML: flat w,h lists
    det = OnnxDetector(model, anchors=cfg)
    assert det.layout.name == "raw" and det.layout.nc == 4
    got = sorted(det(np.zeros((640, 640, 3), np.uint8)), key=lambda d: d.class_id)
    np.testing.assert_allclose([d.xyxy for d in got], boxes, atol=0.05)
    # the default (YOLOv5) anchors read the same heads wrongly: the anchor config matters
    wrong = sorted(OnnxDetector(model)(np.zeros((640, 640, 3), np.uint8)), key=lambda d: d.class_id)
    assert np.abs(np.array([d.xyxy for d in wrong]) - boxes).max() > 5

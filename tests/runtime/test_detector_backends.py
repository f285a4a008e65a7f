"""The faster CPU paths of the detector: the OpenVINO backend (``--providers openvino``), int8 copies from
``radarcal quantise``, and the letterbox in the frame-prefetch thread. Boxes are checked against the generated truth
(``make_square_finder``: a graph whose boxes come from the pixels)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from radarcal.runtime.detector import OnnxDetector
from radarcal.runtime.synthetic_onnx import make_number_classifier, make_square_finder

from test_detector_regions import match, scene

try:
    import openvino  # noqa: F401

    HAVE_OV = True
except ImportError:
    HAVE_OV = False
needs_ov = pytest.mark.skipif(not HAVE_OV, reason="openvino not installed (pip install openvino, or radarcal[speed])")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("backends")
    make_square_finder(d / "sq.onnx", side=24)
    make_square_finder(d / "sq_b1.onnx", side=24, batch=1)
    return d


@needs_ov
@pytest.mark.parametrize("providers, precision", [("openvino", None), ("openvino-f32", "f32"), ("openvino-bf16", "bf16")])
def test_openvino_backend_finds_the_truth(models, providers, precision):
    det = OnnxDetector(models / "sq.onnx", providers=providers, threads=1)
    assert det.model.providers[0].startswith("OpenVINO-CPU-")
    if precision:
        assert det.model.providers[0].endswith(precision)
    assert "OpenVINO-CPU" in det.describe()
    imgs, truths = zip(*[scene((480, 640), 7, s) for s in range(3)])
    for dets, truth in zip(det.detect_batch(list(imgs)), truths):  # batch > 1 on a dynamic-batch graph, non-square frames
        assert match(dets, truth, tol=1e-2) == 0


@needs_ov
def test_openvino_fixed_batch_runs_in_parallel_streams(models):
    det = OnnxDetector(models / "sq_b1.onnx", providers="openvino", threads=1, parallel=2)
    imgs, truths = zip(*[scene((640, 640), 6, s) for s in range(10, 14)])
    for dets, truth in zip(det.detect_batch(list(imgs)), truths):
        assert match(dets, truth, tol=1e-2) == 0
    assert det.model.session.compiled.get_property("NUM_STREAMS") >= 1


def test_openvino_missing_falls_back_to_onnxruntime(models, monkeypatch, capsys):
    import radarcal.runtime.detector as detector

    monkeypatch.setitem(sys.modules, "openvino", None)  # import openvino -> ImportError
    monkeypatch.setattr(detector, "_NOTES_SHOWN", set())
    det = OnnxDetector(models / "sq.onnx", providers="openvino", threads=1)
    assert det.model.providers == ["CPUExecutionProvider"]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install openvino" in err[0] and "running sq.onnx on CPU" in err[0]
    img, truth = scene((640, 640), 5, 3)
    assert match(det(img), truth) == 0


def test_unknown_provider_is_one_line_error(models):
    from radarcal.errors import InputError

    with pytest.raises(InputError, match="unknown provider 'openvinox'"):
        OnnxDetector(models / "sq.onnx", providers="openvinox")


def test_int8_copy_finds_the_truth(models, tmp_path):
    pytest.importorskip("onnx")
    from radarcal.runtime.quantise import quantise_model

    imgs = [scene((640, 640), 8, s)[0] for s in range(6)]
    r = quantise_model(models / "sq.onnx", tmp_path / "sq.int8.onnx", imgs, held_out=[scene((640, 640), 8, s)[0] for s in range(20, 23)])
    assert r["kind"] == "detector" and r["quantised"] == r["convs"] == 2
    a = r["agreement"]
    assert a["boxes"] == 24 and a["matched"] == 1.0 and a["extra"] == 0 and a["iou_min"] > 0.999
    assert a["rel_diff"] < 0.05
    det = OnnxDetector(tmp_path / "sq.int8.onnx", threads=1)
    assert det.layout.name == "yolov8" and det.class_names == ["red", "blue"]  # metadata kept: layout and names read as before
    for s in range(30, 34):
        img, truth = scene((480, 640), 7, s)
        assert match(det(img), truth, tol=1e-2) == 0  # box coordinates stay float (the decode is not quantised)


def test_int8_classifier_keeps_the_float_classes(tmp_path):
    pytest.importorskip("onnx")
    from radarcal.runtime.quantise import quantise_model

    make_number_classifier(tmp_path / "num.onnx", nc=9)
    rng = np.random.default_rng(0)
    crops = [rng.integers(0, 255, (48, 40, 3), dtype=np.uint8) for _ in range(40)]
    r = quantise_model(tmp_path / "num.onnx", tmp_path / "num.int8.onnx", crops[:24], held_out=crops[24:])
    assert r["kind"] == "classifier" and r["quantised"] == r["convs"]
    assert r["agreement"]["top1"] >= 0.9 and r["agreement"]["max_prob_diff"] < 0.05


def test_quantise_cli(models, tmp_path, capsys):
    """The command end to end in-process (bad models / folders / outputs: tests/cli/test_bad_input_matrix.py)."""
    pytest.importorskip("onnx")
    import cv2

    from radarcal.cli.main import main

    (tmp_path / "frames").mkdir()
    for s in range(8):
        cv2.imwrite(str(tmp_path / "frames" / f"{s:03d}.png"), scene((480, 640), 6, s)[0])
    out = tmp_path / "sq.int8.onnx"
    assert main(["quantise", str(models / "sq.onnx"), "--images", str(tmp_path / "frames"), "-o", str(out), "--frames", "4", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert out.is_file() and r["agreement"]["matched"] == 1.0 and r["agreement"]["boxes"] == 24 and r["frames"] == 4 and r["held_out"] == 4
    assert main(["quantise", str(models / "sq.onnx"), "--images", str(tmp_path / "frames"), "-o", str(models / "sq.onnx")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "would overwrite the input" in err[0]


def test_letterbox_in_the_prefetch_thread(models):
    from radarcal.runtime.sources import CameraFrame, prefetch_frames
    from radarcal.runtime.stages import DetectAhead, Recogniser

    det = OnnxDetector(models / "sq.onnx", threads=1)
    ahead = DetectAhead(Recogniser(det), workers=2)
    scenes = [scene((480, 640), 6, s) for s in range(40, 44)]
    frames = [CameraFrame(float(i), f"f{i}", (lambda img=img: img), i) for i, (img, _) in enumerate(scenes)]
    prepared = []

    def prepare(img):
        prepared.append(id(img))
        return ahead.prepare_ahead(img)

    seen = []
    for f in ahead.frames(prefetch_frames(iter(frames), prepare=prepare)):
        seen.append(ahead(f))
    assert len(prepared) == 4 and not det._ahead  # every frame letterboxed ahead, and taken by its detect call
    for dets, (_, truth) in zip(seen, scenes):
        assert match(dets, truth) == 0

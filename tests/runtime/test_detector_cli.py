"""``radarcal run --detector`` end to end on datasets/sample_replay for every export layout, the three stages through
the CLI, and bad models -> one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from radarcal.cli.main import main
from radarcal.runtime.detector import letterbox
from radarcal.runtime.synthetic_onnx import layout_outputs, make_colour_armour_model, make_fixed_outputs_model, make_grey_level_classifier, ultralytics_meta

SAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "sample_replay"
NAMES = [f"{t}_{n}" for t in ("red", "blue") for n in (1, 2, 3, 4, 5, 7)]
LAYOUTS = ["yolov5", "yolov8", "yolov8t", "rows6", "rows7", "split", "dets_labels", "raw"]


@pytest.fixture(scope="module")
def frame0():
    if not (SAMPLE / "meta.json").is_file():
        pytest.skip("datasets/sample_replay missing (python datasets/make_sample.py)")
    rec = json.loads((SAMPLE / "detections.jsonl").read_text().splitlines()[0])
    truth = json.loads((SAMPLE / "truth.jsonl").read_text().splitlines()[0])
    assert rec["frame"] == "000000.jpg"
    return rec["boxes"], {r["label"]: r["p_field"] for r in truth["robots"]}


def _model(path, layout, boxes, meta=None):
    """A graph emitting the sample's frame-0 boxes (1280x1024 -> 640 letterbox) in ``layout``."""
    _, r, (px, py) = letterbox(np.zeros((1024, 1280, 3), np.uint8), 640)
    lb = np.array([np.asarray(b["xyxy"]) * r + [px, py, px, py] for b in boxes])
    cls = np.array([NAMES.index(b["label"]) for b in boxes])
    outs = layout_outputs(layout, [(lb, cls, np.array([b["score"] for b in boxes]))], len(NAMES), 640)
    make_fixed_outputs_model(path, outs, (1, 3, 640, 640), meta if meta is not None else ultralytics_meta(NAMES) if layout.startswith("yolov8") else
                             {"names": repr(dict(enumerate(NAMES)))})  # fmt: skip


def _robots(out: Path) -> dict[str, tuple[float, float]]:
    first = json.loads(out.read_text().splitlines()[0])
    return {r["label"]: (r["x"], r["y"]) for r in first["robots"]}


@pytest.mark.slow
def test_every_layout_puts_the_same_robots_on_the_field(frame0, tmp_path, capsys):
    boxes, truth = frame0
    placed = {}
    for layout in LAYOUTS:
        model = tmp_path / f"{layout}.onnx"
        _model(model, layout, boxes)
        out = tmp_path / f"{layout}.jsonl"
        assert main(["run", "--replay", str(SAMPLE), "--localise", "box", "--detector", str(model), "--max-frames", "1", "--out", str(out), "--json"]) == 0, layout
        placed[layout] = _robots(out)
    capsys.readouterr()
    ref = placed["yolov5"]
    assert len(ref) == len(boxes) == 6
    for label, (x, y) in ref.items():  # the YOLOv5 layout: all six within 1 m of the truth
        assert np.hypot(x - truth[label][0], y - truth[label][1]) < 1.0, label
    for layout, robots in placed.items():  # every other layout: the same robots at the same places
        assert set(robots) == set(ref), layout
        for label, (x, y) in robots.items():
            assert np.hypot(x - ref[label][0], y - ref[label][1]) < 0.01, (layout, label)


def test_one_layout_quick_and_status_line(frame0, tmp_path, capsys):
    boxes, truth = frame0
    model = tmp_path / "v8.onnx"
    _model(model, "yolov8", boxes)
    out = tmp_path / "o.jsonl"
    assert main(["run", "--replay", str(SAMPLE), "--localise", "box", "--detector", str(model), "--max-frames", "2", "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "yolov8" in cap.err and "(robot " in cap.err  # model summary line; detector stage in the status line
    robots = _robots(out)
    assert len(robots) == 6 and all(np.hypot(x - truth[k][0], y - truth[k][1]) < 1.0 for k, (x, y) in robots.items())
    line = json.loads(out.read_text().splitlines()[0])
    assert "detect_robot" in line["latency_ms"]


def test_three_stages_through_the_cli(frame0, tmp_path, capsys):
    """Robot boxes labelled 'robot'; the armour graph reads colour from the crop: the sample's robots are drawn in
    their team colour, so the armour stage must give the one red robot red and the others blue."""
    boxes, truth = frame0
    model = tmp_path / "robot.onnx"
    _, r, (px, py) = letterbox(np.zeros((1024, 1280, 3), np.uint8), 640)
    lb = np.array([np.asarray(b["xyxy"]) * r + [px, py, px, py] for b in boxes])
    make_fixed_outputs_model(model, layout_outputs("yolov8", [(lb, np.zeros(len(lb), int), np.full(len(lb), 0.9))], 1, 640), (1, 3, 640, 640),
                             ultralytics_meta(["robot"]))  # fmt: skip
    armour = tmp_path / "armour.onnx"
    make_colour_armour_model(armour, 192, names=("blue", "red", "dead"), margin=0.02)
    (tmp_path / "armour.yaml").write_text("nc: 3\nnames: [blue, red, dead]\n")
    number = tmp_path / "number.onnx"
    make_grey_level_classifier(number, [0.0, 1.0], ["negative", "3"], 64)  # the sample's armour crops are dark: "negative"
    out = tmp_path / "o.jsonl"
    assert main(["run", "--replay", str(SAMPLE), "--localise", "box", "--detector", str(model), "--armour", str(armour), "--armour-names", str(tmp_path / "armour.yaml"),
                 "--number", str(number), "--max-frames", "1", "--out", str(out), "--json"]) == 0  # fmt: skip
    capsys.readouterr()
    first = json.loads(out.read_text().splitlines()[0])
    robots = _robots(out)
    assert set(robots) == {"red_unknown", "blue_unknown"}  # no number read: one track per colour (the best-scored box)
    x, y = robots["red_unknown"]
    assert np.hypot(x - truth["red_3"][0], y - truth["red_3"][1]) < 1.0  # the red crop was the red robot's
    assert set(first["latency_ms"]) >= {"detect_robot", "detect_armour", "detect_number"}


def test_dead_robot_tracked_but_not_sent(frame0):
    from radarcal.bundle import load_bundle
    from radarcal.runtime.detector import Detection
    from radarcal.runtime.loop import Pipeline, RunConfig

    boxes, _ = frame0
    b = load_bundle(SAMPLE / "calib.yaml")
    sent = {}
    for dead in (False, True):
        pipe = Pipeline(b, "cam0", None, RunConfig.from_bundle(b, team="red", season=2024, sentry_xy=(5.0, 7.5)))
        dets = [Detection(np.asarray(d["xyxy"], float), d["label"], d["score"], dead=dead and d["label"] == "blue_3") for d in boxes]
        res = pipe.process(0.0, "000000.jpg", dets)
        blue3 = next(r for r in res.robots if r.label == "blue_3")
        assert blue3.dead is dead and blue3.to_dict().get("dead", False) is dead
        (payload,) = [data for cmd, data, _ in pipe.referee_messages(res, "red") if cmd == 0x0305]
        sent[dead] = payload
        if dead:
            assert res.sentry["target"] != "blue_3"
    # 2024 layout: u16 cm x, y for hero, engineer, infantry 3, 4, 5, sentry: blue_3's slot is bytes 8..11
    assert sent[False][8:12] != bytes(4) and sent[True][8:12] == bytes(4)
    assert sent[False][:8] == sent[True][:8] and sent[False][12:] == sent[True][12:]


def _bad(args, capsys):
    code = main(["run", "--replay", str(SAMPLE), "--max-frames", "1", "--json", *args])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err


def test_bad_models_one_line_exit_2(frame0, tmp_path, capsys):
    boxes, _ = frame0
    notonnx = tmp_path / "model.onnx"
    notonnx.write_text("this is not a model\n")
    code, err = _bad(["--detector", str(notonnx)], capsys)
    assert code == 2 and err[-1].startswith("error: ") and "model.onnx" in err[-1] and "cannot load" in err[-1]
    rank3 = tmp_path / "rank3.onnx"
    make_fixed_outputs_model(rank3, {"output0": np.zeros((1, 100, 17), np.float32)}, (3, 640, 640))
    code, err = _bad(["--detector", str(rank3)], capsys)
    assert code == 2 and "rank 3" in err[-1] and "N x C x H x W" in err[-1]
    odd = tmp_path / "odd.onnx"
    make_fixed_outputs_model(odd, {"output0": np.zeros((1, 5), np.float32)}, (1, 3, 640, 640))
    code, err = _bad(["--detector", str(odd)], capsys)
    assert code == 2 and "input images 1x3x640x640" in err[-1] and "output output0 1x5" in err[-1]
    good = tmp_path / "v8.onnx"
    _model(good, "yolov8", boxes)
    (tmp_path / "names.txt").write_text("red_1\nblue_1\nred_3\n")
    code, err = _bad(["--detector", str(good), "--names", str(tmp_path / "names.txt")], capsys)
    assert code == 2 and "names.txt" in err[-1] and "3 class names but v8.onnx has 12 classes" in err[-1]
    code, err = _bad(["--detector", str(good), "--detector-layout", "yolov9000"], capsys)
    assert code == 2 and "yolov9000" in err[-1]
    code, err = _bad(["--detector", str(good), "--number", str(good)], capsys)  # a detector given as the number classifier
    assert code == 2 and "v8.onnx" in err[-1] and "number classifier: expected one N x classes output" in err[-1]
    code, err = _bad(["--number", str(good)], capsys)
    assert code == 2 and "--number" in err[-1] and "needs --detector" in err[-1]
    code, err = _bad(["--detector", str(good), "--providers", "tpu9"], capsys)
    assert code == 2 and "tpu9" in err[-1]
    assert len([ln for ln in err if ln.startswith("error")]) == 1


def test_missing_gpu_provider_falls_back_to_cpu(frame0, tmp_path, capsys):
    import onnxruntime as ort

    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("onnxruntime-gpu is installed here: the fallback is not exercised")
    boxes, _ = frame0
    good = tmp_path / "v5.onnx"
    _model(good, "yolov5", boxes)
    assert main(["run", "--replay", str(SAMPLE), "--detector", str(good), "--providers", "tensorrt,cuda", "--max-frames", "1", "--json"]) == 0
    cap = capsys.readouterr()
    notes = [ln for ln in cap.err.splitlines() if "CUDAExecutionProvider" in ln]
    assert len(notes) == 1 and "onnxruntime-gpu" in notes[0] and "CPU" in notes[0]
    assert json.loads(cap.out)["frames"] == 1


def test_early_stop_exits_cleanly_in_a_real_process(frame0, tmp_path):
    """--max-frames stops while the decode thread is still busy: the process must still exit 0 (it aborted with 134,
    'terminate called without an active exception', when a thread was left inside OpenCV at interpreter exit)."""
    import subprocess
    import sys

    boxes, _ = frame0
    model = tmp_path / "v8.onnx"
    _model(model, "yolov8", boxes)
    root = Path(__file__).resolve().parents[2]
    for extra in ([], ["--no-detect-ahead"]):
        p = subprocess.run([sys.executable, "-m", "radarcal", "run", "--replay", str(SAMPLE), "--detector", str(model), "--max-frames", "1", "--json", *extra],
                           cwd=root, capture_output=True, text=True, timeout=120)  # fmt: skip
        assert p.returncode == 0, (extra, p.stderr[-300:])
        assert json.loads(p.stdout)["frames"] == 1

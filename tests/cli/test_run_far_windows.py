"""``radarcal run --roi-windows``: the run places native-resolution detector windows around its far LiDAR tracks
and the far robot gets its name; without the windows the full-frame letterbox never sees it. The replay is the
sample's clouds and truth with images holding one 24 px blue square where the truth puts blue_1 (11.7 m, tracked
by the LiDAR), found by a graph whose boxes come from the pixels (``synthetic_onnx.make_square_finder``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from radarcal.cli.main import main
from radarcal.runtime.synthetic_onnx import make_square_finder

SAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "sample_replay"
SIDE = 24


@pytest.fixture(scope="module")
def square_replay(tmp_path_factory):
    if not (SAMPLE / "meta.json").is_file():
        pytest.skip("datasets/sample_replay missing (python datasets/make_sample.py)")
    root = tmp_path_factory.mktemp("far_replay")
    rep = root / "rep"
    rep.mkdir()
    for name in ("calib.yaml", "meta.json", "truth.jsonl", "truth.json"):
        shutil.copy(SAMPLE / name, rep / name)
    shutil.copytree(SAMPLE / "clouds", rep / "clouds")
    (rep / "images").mkdir()
    shutil.copy(SAMPLE / "images" / "times.csv", rep / "images" / "times.csv")
    truth = {(t := json.loads(x))["frame"]: t for x in (SAMPLE / "truth.jsonl").read_text().splitlines()}
    rng = np.random.default_rng(0)
    for p in sorted((SAMPLE / "images").glob("*.jpg")):
        x1, y1, x2, y2 = next(r["xyxy"] for r in truth[p.name]["robots"] if r["label"] == "blue_1")
        img = rng.integers(40, 80, (1024, 1280, 3), dtype=np.uint8)
        a, b = int(round((x1 + x2) / 2)) - SIDE // 2, int(round((y1 + y2) / 2)) - SIDE // 2
        img[b : b + SIDE, a : a + SIDE] = (255, 0, 0)
        cv2.imwrite(str(rep / "images" / p.name), img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    model = root / "sq.onnx"
    make_square_finder(model, side=SIDE, names=("red_1", "blue_1"))
    return rep, model, truth


def _run(rep: Path, model: Path, out: Path, capsys, windows: str) -> tuple[dict, list[dict]]:
    code = main(["run", "--replay", str(rep), "--detector", str(model), "--roi-windows", windows, "--threads", "1", "--out", str(out), "--json", "-q"])
    assert code == 0
    return json.loads(capsys.readouterr().out), [json.loads(x) for x in out.read_text().splitlines()]


def test_run_places_windows_around_far_tracks(square_replay, tmp_path, capsys):
    rep, model, truth = square_replay
    named = {}
    for windows in ("2", "0"):
        s, lines = _run(rep, model, tmp_path / f"w{windows}.jsonl", capsys, windows)
        assert s["frames"] == 30  # the frames with an image (and a cloud to pair with)
        hits = 0
        for ln in lines:
            p = next(r["p_field"] for r in truth[ln["frame"]]["robots"] if r["label"] == "blue_1")
            hits += any(r["label"] == "blue_1" and np.hypot(r["x"] - p[0], r["y"] - p[1]) < 0.5 for r in ln["robots"])
        named[windows] = hits
        if windows == "2":
            rw = s["roi_windows"]
            assert rw["max_windows"] == 2 and rw["windows_run"] >= 20 and rw["boxes_added"] >= 20
            assert "detect_regions" in s["latency_ms"]
        else:
            assert "roi_windows" not in s and "detect_regions" not in s["latency_ms"]
    assert named["0"] == 0  # 12 px in the 640 letterbox: never found, the track stays unnamed
    assert named["2"] >= 20  # of 30 frames: found in the windows from the first frames the LiDAR tracks it

"""Robot -> armour -> number stages on a painted frame: the armour graph's class follows each crop's colour, the
number graph's class follows each armour crop's grey level, so every label checks that its crop was cut,
letterboxed, batched and mapped back to the right robot."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.runtime.detector import OnnxDetector, letterbox
from radarcal.runtime.stages import NumberClassifier, Recogniser, combine_label, parse_armour_label, parse_number_label
from radarcal.runtime.synthetic_onnx import layout_outputs, make_colour_armour_model, make_fixed_outputs_model, make_grey_level_classifier, ultralytics_meta

ARMOUR_BOX = (0.35, 0.6, 0.65, 0.8)  # where the armour graph puts its box, fractions of its 192 px letterboxed input
NUMBERS = ["1", "2", "3", "4", "5", "7", "negative"]
LEVELS = [0.15, 0.25, 0.35, 0.45, 0.55, 0.65, 0.9]
# robots: (xyxy in the 1280x1024 frame, robot-detector label, BGR body colour, number painted on the armour)
ROBOTS = [([100, 300, 260, 420], "robot", (40, 30, 220), "3"),  # red 3
          ([600, 350, 700, 500], "robot", (220, 40, 30), "1"),  # blue 1 (a tall box: other letterbox pads)
          ([900, 400, 1100, 470], "red_4", (128, 128, 128), "4"),  # grey armour: dead; the robot detector's colour stays
          ([300, 700, 380, 760], "blue_7", (200, 60, 40), "negative")]  # fmt: skip


def _armour_xyxy(robot_xyxy, hw=(1024, 1280), margin=0.05, size=192):
    """Where the armour box lands in the frame: the crop (box + 5 % margin, whole pixels) letterboxed to 192 px, mapped back."""
    x1, y1, x2, y2 = robot_xyxy
    mx, my = (x2 - x1) * margin, (y2 - y1) * margin
    a, b = int(max(np.floor(x1 - mx), 0)), int(max(np.floor(y1 - my), 0))
    c, d = int(min(np.ceil(x2 + mx) + 1, hw[1])), int(min(np.ceil(y2 + my) + 1, hw[0]))
    _, r, (px, py) = letterbox(np.zeros((d - b, c - a, 3), np.uint8), size)
    f = (np.asarray(ARMOUR_BOX) * size - [px, py, px, py]) / r
    f = np.clip(f, 0, [c - a - 1, d - b - 1, c - a - 1, d - b - 1])  # a box reaching past its crop ends at the crop's edge
    return f + [a, b, a, b]


def _scene(tmp_path):
    img = np.zeros((1024, 1280, 3), np.uint8)
    for xyxy, _, colour, number in ROBOTS:
        x1, y1, x2, y2 = xyxy
        img[y1 : y2 + 1, x1 : x2 + 1] = colour
        ax1, ay1, ax2, ay2 = _armour_xyxy(xyxy)
        g = int(round(LEVELS[NUMBERS.index(number)] * 255))
        img[int(np.floor(ay1)) : int(np.ceil(ay2)) + 1, int(np.floor(ax1)) : int(np.ceil(ax2)) + 1] = g
    names = ["robot", "red_4", "blue_7"]
    _, r, (px, py) = letterbox(img, 640)
    boxes = np.array([np.asarray(b, float) * r + [px, py, px, py] for b, *_ in ROBOTS])
    cls = np.array([names.index(lab) for _, lab, _, _ in ROBOTS])
    robot = tmp_path / "robot.onnx"
    make_fixed_outputs_model(robot, layout_outputs("yolov8", [(boxes, cls, np.full(len(cls), 0.9))], 3), (1, 3, 640, 640), ultralytics_meta(names))
    armour = tmp_path / "armour.onnx"
    make_colour_armour_model(armour, 192, ARMOUR_BOX, ("blue", "red", "dead"))
    number = tmp_path / "number.onnx"
    make_grey_level_classifier(number, LEVELS, NUMBERS, 64)
    return img, robot, armour, number


def test_three_stages_label_robots_from_their_armour(tmp_path):
    img, robot, armour, number = _scene(tmp_path)
    rec = Recogniser(OnnxDetector(robot, threads=1), OnnxDetector(armour, threads=1), NumberClassifier(number, threads=1))
    dets = sorted(rec(img), key=lambda d: d.xyxy[0])
    by_x = sorted(ROBOTS, key=lambda r: r[0][0])
    assert [d.label for d in dets] == ["red_3", "blue_7", "blue_1", "red_4"]
    assert [d.dead for d in dets] == [False, False, False, True]
    assert [d.armour_label for d in dets] == ["red", "blue", "blue", "dead"]
    assert [d.number_label for d in dets] == ["3", "negative", "1", "4"]
    for d, (xyxy, *_rest) in zip(dets, by_x):
        np.testing.assert_allclose(d.xyxy, xyxy, atol=1e-3)  # the robot box is untouched
        np.testing.assert_allclose(d.armour_xyxy, _armour_xyxy(xyxy), atol=1e-3)  # armour box back in frame pixels
    assert set(rec.last_timings_ms) == {"robot", "armour", "number"}
    # two frames: the robot graph (fixed batch 1) runs twice, armour and number once each on all 8 crops (dynamic batch)
    both = rec([img, img])
    assert [sorted(d.label for d in b) for b in both] == [sorted(d.label for d in dets)] * 2


def test_armour_without_number_stage_and_no_armour(tmp_path):
    img, robot, armour, _ = _scene(tmp_path)
    rec = Recogniser(OnnxDetector(robot, threads=1), OnnxDetector(armour, threads=1))
    labels = sorted((d.label, d.dead) for d in rec(img))
    # colour from the armour, number from the robot label when it has one
    assert labels == [("blue_7", False), ("blue_unknown", False), ("red_4", True), ("red_unknown", False)]
    blank = np.zeros_like(img)  # crops of pure black: armour graph says grey for every robot
    assert all(d.dead for d in rec(blank))
    assert Recogniser(OnnxDetector(robot, threads=1))(img)[0].armour_label is None


def test_number_classifier_on_robot_crops_without_armour(tmp_path):
    """Detector + classifier (no armour stage): the classifier reads the whole robot crop; colour from the robot label."""
    img, robot, _, _ = _scene(tmp_path)
    levels = {"red_4": 0.45, "blue_7": 0.65}
    for xyxy, label, _, _ in ROBOTS:
        x1, y1, x2, y2 = xyxy
        img[y1 : y2 + 1, x1 : x2 + 1] = int(round(levels.get(label, 0.9) * 255))  # each robot body in its number's grey level
    number = tmp_path / "n3.onnx"
    make_grey_level_classifier(number, [0.45, 0.65, 0.9], ["4", "sentry", "negative"], 32, channels=3)
    rec = Recogniser(OnnxDetector(robot, threads=1), number=NumberClassifier(number, threads=1), crop_margin=0.05)
    got = sorted((d.label, d.number_label) for d in rec(img))
    assert got == [("blue_7", "sentry"), ("red_4", "4"), ("robot", "negative"), ("robot", "negative")]
    assert set(rec.last_timings_ms) == {"robot", "number"}


@pytest.mark.parametrize(("label", "parsed"), [("red", ("red", None, False)), ("B1", ("blue", 1, False)), ("R3", ("red", 3, False)),
                                               ("armor_blue_sentry", ("blue", 7, False)), ("dead", ("grey", None, True)),
                                               ("gray_4", ("grey", 4, True)), ("purple", ("grey", None, True)), ("sentry", (None, 7, False))])  # fmt: skip
def test_armour_label_parsing(label, parsed):
    assert parse_armour_label(label) == parsed


def test_number_and_combined_labels():
    assert [parse_number_label(s) for s in ("3", "B4", "sentry", "hero", "negative", "outpost", "0", None)] == [3, 4, 7, 1, None, None, None, None]
    assert combine_label("robot", "red", "3") == ("red_3", False)
    assert combine_label("blue_2", "dead", None) == ("blue_2", True)
    assert combine_label("red_1", "blue", "5") == ("blue_5", False)  # the armour overrules the silhouette
    assert combine_label("car", None, None) == ("car", False)


def test_detect_ahead_same_results_in_order_and_errors_reraised(tmp_path):
    from radarcal.errors import InputError
    from radarcal.runtime.sources import CameraFrame
    from radarcal.runtime.stages import DetectAhead

    img, robot, armour, number = _scene(tmp_path)
    rec = Recogniser(OnnxDetector(robot, threads=1), OnnxDetector(armour, threads=1), NumberClassifier(number, threads=1))
    want = sorted(d.label for d in rec(img))
    imgs = [img, np.zeros_like(img), None, img]  # None: an unreadable frame

    def load(k):
        if imgs[k] is None:
            raise InputError(f"{k:06d}.jpg", "cannot decode image")
        return imgs[k]

    src = [CameraFrame(k / 30, f"{k:06d}.jpg", (lambda k=k: load(k)), k) for k in range(4)]
    ahead = DetectAhead(rec)
    got = []
    for f in ahead.frames(iter(src)):
        try:
            got.append((f.index, sorted(d.label for d in ahead(f))))
        except InputError as e:
            got.append((f.index, str(e)))
    assert [g[0] for g in got] == [0, 1, 2, 3]
    assert got[0][1] == want and got[3][1] == want
    assert got[1][1] == sorted(d.label for d in rec(np.zeros_like(img)))  # black frame: every armour grey
    assert got[2][1] == "000002.jpg: cannot decode image"
    assert set(ahead.last_timings_ms) == {"robot", "armour", "number"}

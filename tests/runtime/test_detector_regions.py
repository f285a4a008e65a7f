"""Regions of interest and tiles of large frames, letterbox into a buffer, preprocessing ahead, parallel runs and
the multi-worker detect-ahead: all checked against known boxes on generated images, through a graph whose boxes come
from the pixels (:func:`radarcal.runtime.synthetic_onnx.make_square_finder`: solid 24 px red / blue squares)."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.runtime.detector import OnnxDetector, letterbox, plan_rois, tile_grid
from radarcal.runtime.synthetic_onnx import make_square_finder

SIDE = 24
BG = 60


@pytest.fixture(scope="module")
def finder(tmp_path_factory):
    d = tmp_path_factory.mktemp("sq")
    make_square_finder(d / "sq.onnx", side=SIDE)
    make_square_finder(d / "sq_b1.onnx", side=SIDE, batch=1)
    return d


def scene(hw, n, seed, spacing=40):
    """A frame of ``hw`` with ``n`` squares (top-left corners on multiples of 4, at least ``spacing`` px apart) and
    the truth {(label, xyxy)}: pixel centres at integers, so a square of pixels a..a+23 is [a-0.5, a+23.5]."""
    rng = np.random.default_rng(seed)
    H, W = hw
    img = rng.integers(BG - 20, BG + 20, (H, W, 3), dtype=np.uint8)
    truth, taken = [], []
    while len(truth) < n:
        a, b = 4 * int(rng.integers(2, (W - SIDE - 8) // 4)), 4 * int(rng.integers(2, (H - SIDE - 8) // 4))
        if any(abs(a - x) < SIDE + spacing and abs(b - y) < SIDE + spacing for x, y in taken):
            continue
        taken.append((a, b))
        red = len(truth) % 2 == 0
        img[b : b + SIDE, a : a + SIDE] = (0, 0, 255) if red else (255, 0, 0)
        truth.append(("red" if red else "blue", np.array([a - 0.5, b - 0.5, a + SIDE - 0.5, b + SIDE - 0.5])))
    return img, truth


def match(dets, truth, tol=1e-3):
    """Every truth box found exactly once with its label; returns the number of extra detections."""
    used = set()
    for label, box in truth:
        hits = [i for i, d in enumerate(dets) if d.label == label and np.abs(d.xyxy - box).max() < tol]
        assert len(hits) == 1, (label, box, [(d.label, d.xyxy) for d in dets])
        used.add(hits[0])
    return len(dets) - len(used)


def test_letterbox_into_buffer_is_the_same_image():
    rng = np.random.default_rng(0)
    for hw, size in (((1024, 1280), 640), ((900, 500), 640), ((640, 640), 640), ((480, 640), (384, 640)), ((300, 200), 640)):
        for shape in (hw + (3,), hw):
            img = rng.integers(0, 255, shape, dtype=np.uint8)
            ref, r0, p0 = letterbox(img, size)
            buf = np.full(ref.shape, 7, np.uint8)  # stale content must be overwritten everywhere
            got, r1, p1 = letterbox(img, size, out=buf)
            assert got is buf and (r0, p0) == (r1, p1)
            np.testing.assert_array_equal(got, ref)
    small = rng.integers(0, 255, (100, 200, 3), dtype=np.uint8)
    lb, r, pad = letterbox(small, 640, scaleup=False)
    assert r == 1.0 and pad == (220.0, 270.0)
    np.testing.assert_array_equal(lb[270:370, 220:420], small)


def test_full_frame_finds_the_squares(finder):
    det = OnnxDetector(finder / "sq.onnx", threads=1)
    img, truth = scene((480, 640), 8, 1)  # letterbox scale 1 (pad 80 rows): the squares keep their 24 px
    assert match(det(img), truth) == 0


def test_regions_match_full_frame_and_merge_without_duplicates(finder):
    det = OnnxDetector(finder / "sq.onnx", threads=1)
    img, truth = scene((480, 640), 8, 2)
    full = det(img)
    assert match(full, truth) == 0
    centres = [0.5 * (b[:2] + b[2:]) for _, b in truth[:4]]
    rois = plan_rois(np.array(centres), img.shape[:2], 320, max_rois=3, margin=SIDE)
    assert 1 <= len(rois) <= 3 and np.all(rois[:, 2] - rois[:, 0] == 320) and np.all(rois[:, 3] - rois[:, 1] == 320)
    assert rois[:, 0].min() >= 0 and rois[:, 2].max() <= 640 and rois[:, 3].max() <= 480
    found = det.detect_regions(img, rois)
    inside = [(lab, b) for lab, b in truth if any(r[0] <= b[0] and r[1] <= b[1] and b[2] <= r[2] and b[3] <= r[3] for r in rois)]
    assert len(inside) >= 3
    assert match(found, inside) == 0  # same boxes as full frame, and nothing from squares cut by a window's border
    assert det.last_timings_ms["regions"] == len(rois)
    merged = det.detect_regions(img, rois, full=full)
    assert match(merged, truth) == 0  # each square once


def test_tiles_find_small_robots_the_full_frame_misses(finder):
    det = OnnxDetector(finder / "sq.onnx", threads=1)
    img, truth = scene((1440, 1920), 14, 3)
    # squares straddling tile borders too (x 424..640, y 400..640 are the overlaps of tile_grid's windows)
    img[600:624, 620:644] = (0, 0, 255)
    truth.append(("red", np.array([619.5, 599.5, 643.5, 623.5])))
    full = det(img)  # letterboxed by 1/3: the squares shrink to 8 px and score ~1e-4
    assert not any(any(d.label == lab and np.abs(d.xyxy - b).max() < 2 for lab, b in truth) for d in full)
    tiles = tile_grid(img.shape[:2], 640, overlap=64, align=4)
    assert len(tiles) == 12
    found = det.detect_regions(img, tiles, full=full)
    assert match(found, truth) == 0


def test_prepare_ahead_and_parallel_runs_give_the_same_detections(finder):
    imgs = [scene((480, 640), 5, s)[0] for s in (4, 5, 6)]
    dyn = OnnxDetector(finder / "sq.onnx", threads=1)
    ref = dyn.detect_batch(imgs)
    fixed = OnnxDetector(finder / "sq_b1.onnx", threads=1, parallel=2)
    assert fixed.model.batch == 1
    for img in imgs[:2]:
        assert fixed.prepare_ahead(img) is img
    got = fixed.detect_batch(imgs)  # two prepared in the "prefetch" step, one not; three runs on two threads
    assert not fixed._ahead
    for a, b in zip(ref, got):
        assert [d.label for d in a] == [d.label for d in b]
        np.testing.assert_allclose([d.xyxy for d in a], [d.xyxy for d in b], atol=1e-4)
    other = scene((480, 640), 2, 7)[0]
    fixed.prepare_ahead(other)
    copy = other.copy()  # a different array with the same pixels is not taken for the prepared one
    assert fixed._take(copy) is None and fixed._take(other) is not None


def test_detect_ahead_with_two_workers_keeps_frame_order(finder):
    from radarcal.runtime.stages import DetectAhead, Recogniser

    class Frame:
        def __init__(self, img):
            self.img = img

        def load(self):
            return self.img

    scenes = [scene((480, 640), 1 + k % 4, 10 + k) for k in range(9)]
    rec = Recogniser(OnnxDetector(finder / "sq_b1.onnx", threads=1))
    ahead = DetectAhead(rec, workers=2)
    n = 0
    for f in ahead.frames(iter([Frame(img) for img, _ in scenes])):
        assert match(ahead(f), scenes[n][1]) == 0
        assert "robot" in ahead.last_timings_ms
        n += 1
    assert n == len(scenes)

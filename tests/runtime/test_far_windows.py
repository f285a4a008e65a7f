"""Far-robot windows (``radarcal run --roi-windows``, :mod:`radarcal.runtime.far_windows`): a far robot, 24 px at
native resolution, is lost in the full-frame letterbox of a large frame and found in a window placed around its
projected track; checked with a graph whose boxes come from the pixels (``synthetic_onnx.make_square_finder``)."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.runtime.detector import OnnxDetector
from radarcal.runtime.far_windows import FarWindows, auto_windows
from radarcal.runtime.pipeline import FrameResult, RobotOut
from radarcal.runtime.stages import Recogniser
from radarcal.runtime.synthetic_onnx import make_square_finder

SIDE = 24
HW = (1440, 1920)  # 3x a 640 input: the full-frame letterbox shrinks the square to 8 px


@pytest.fixture(scope="module")
def finder(tmp_path_factory):
    p = tmp_path_factory.mktemp("far") / "sq.onnx"
    make_square_finder(p, side=SIDE, names=("red_1", "blue_3"))  # red squares -> red_1, blue squares -> blue_3
    return p


def looking_along_x(xyz=(0.0, 7.5, 1.5)) -> np.ndarray:
    """T_cam_field of a camera at ``xyz`` (field m) looking along field +x (camera z), image x = field -y."""
    R_field_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return geometry.invert_T(geometry.make_T(R_field_cam, np.asarray(xyz, float)))


def frame_with_square(uv: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A noisy grey frame with a blue 24 px square centred near ``uv``; its truth xyxy (pixel centres at integers)."""
    rng = np.random.default_rng(seed)
    img = rng.integers(40, 80, HW + (3,), dtype=np.uint8)
    a, b = int(round(uv[0])) - SIDE // 2, int(round(uv[1])) - SIDE // 2
    img[b : b + SIDE, a : a + SIDE] = (255, 0, 0)
    return img, np.array([a - 0.5, b - 0.5, a + SIDE - 0.5, b + SIDE - 0.5])


def result(points) -> FrameResult:
    return FrameResult(0.0, "f", [RobotOut(None, np.asarray(p, float), "lidar", 0.1, None, None, None) for p in points], None, None, {})


def test_auto_windows_only_on_frames_much_larger_than_the_input():
    assert auto_windows((3036, 4024), (640, 640)) == 2 and auto_windows(HW, (640, 640)) == 2
    assert auto_windows((1024, 1280), (640, 640)) == 0 and auto_windows((480, 640), (640, 640)) == 0


def test_window_around_a_far_track_finds_the_robot_the_full_frame_misses(finder):
    cam = Camera((HW[1], HW[0]), np.array([[1500.0, 0, 959.5], [0, 1500.0, 719.5], [0, 0, 1]]), np.zeros(5))
    T_cam_field = looking_along_x()
    far_robot, near_robot = np.array([20.0, 6.0, 0.0]), np.array([3.0, 8.0, 0.0])
    uv, ok, z = cam.project_from(T_cam_field, np.array([far_robot + [0, 0, 0.25]]))
    assert ok[0] and z[0] == pytest.approx(20.0)
    img, truth = frame_with_square(uv[0])
    det = OnnxDetector(finder, threads=1)
    rec = Recogniser(det)
    assert not [d for d in rec(img) if d.label == "blue_3"]  # 8 px in the letterbox: score ~0
    far = FarWindows({"cam0": (cam, T_cam_field), "cam1": (cam, looking_along_x((28.0, 7.5, 1.5)))}, det.input_size)  # cam1: both robots behind it
    rec.far = far
    far.observe(0, result([far_robot, near_robot]))
    win = far.windows("cam0", HW)
    assert len(win) == 1 and np.all(win[:, 2] - win[:, 0] == 640)  # the near robot (125 px expected, 42 in the letterbox) gets none
    assert win[0, 0] <= truth[0] and truth[2] <= win[0, 2] and win[0, 1] <= truth[1] and truth[3] <= win[0, 3]
    assert not len(far.windows("cam1", HW))
    got = rec.detect_batch([img, img], cameras=["cam0", "cam1"])
    hits = [d for d in got[0] if d.label == "blue_3"]
    assert len(hits) == 1 and np.abs(hits[0].xyxy - truth).max() < 2.5  # native pixels: the square's own box
    assert not [d for d in got[1] if d.label == "blue_3"]
    assert "regions" in rec.last_timings_ms
    s = far.summary()
    assert (s["frames_with_windows"], s["windows_run"], s["boxes_added"], s["max_windows"]) == (1, 1, 1, "auto")
    far.max_windows = 0
    assert not len(far.windows("cam0", HW))


def test_full_frame_box_gives_way_to_the_window_box_whatever_its_label(finder):
    img = np.full((480, 640, 3), 60, np.uint8)
    img[100:124, 200:224] = (255, 0, 0)
    det = OnnxDetector(finder, threads=1)
    full = det(img)
    assert [d.label for d in full] == ["blue_3"]
    full[0].label = "blue_4"  # the full frame misread the number
    merged = det.detect_regions(img, np.array([[0.0, 0.0, 640.0, 480.0]]), full=full)
    assert [d.label for d in merged] == ["blue_3"]  # one robot, one box: the window's

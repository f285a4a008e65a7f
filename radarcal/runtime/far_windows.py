"""Native-resolution detector windows around far robots (issue #19, ``radarcal run --roi-windows K``).

On a frame much larger than the detector's input (a 12 MP camera into a 640 network: x0.16) the full-frame
letterbox shrinks a far robot to a few pixels, too few to be found or read. The run already knows where its robots
are: every output entry of the last frame (LiDAR-first tracks, box-only and the box path's tracks, predicted ones
included) is projected into each camera, and those whose expected box height *at the full-frame letterbox scale*
is below ``far_px`` get windows of the detector's input size around them (:func:`radarcal.runtime.detector.plan_rois`,
the smallest first, at most K per frame). The windows are detected at native resolution in one batched call
(:meth:`radarcal.runtime.detector.OnnxDetector.detect_regions`) and merged with the full-frame boxes there; the
armour / number stages then read the merged boxes (:class:`radarcal.runtime.stages.Recogniser`).

Threads: :meth:`FarWindows.observe` runs in the loop's thread after each frame and replaces the targets in one
assignment; :meth:`FarWindows.detect` runs in the detect workers and reads them (one or two frames old with
detection ahead: a far robot moves a few pixels, inside ``plan_rois``' 48 px margin).
"""

from __future__ import annotations

import threading

import numpy as np

from radarcal.runtime.detector import plan_rois

__all__ = ["FarWindows", "auto_windows", "ROBOT_HEIGHT_M", "FAR_PX", "AUTO_MIN_RATIO", "AUTO_WINDOWS"]

ROBOT_HEIGHT_M = 0.5  # a ground robot's height (RoboMaster 0.45-0.6 m): the expected box height
FAR_PX = 32.0  # far: expected box height below this many pixels of the full-frame detector input
AUTO_MIN_RATIO = 3.0  # --roi-windows auto: on when the frame's long side is at least this many detector inputs
AUTO_WINDOWS = 2  # windows per frame in auto mode (12 MP + 2 windows: >= 10 FPS on 2 cores, docs/runtime.md)


def auto_windows(frame_hw: tuple[int, int], input_hw: tuple[int, int]) -> int:
    """Windows per frame when ``--roi-windows`` is not given: :data:`AUTO_WINDOWS` on a frame at least
    :data:`AUTO_MIN_RATIO` times the detector input (long side), else none (a 1280x1024 frame is 2x a 640 input:
    the windows would cost a second detector run for little)."""
    return AUTO_WINDOWS if max(frame_hw) >= AUTO_MIN_RATIO * max(input_hw) else 0


class FarWindows:
    """Where to run the detector at native resolution. ``views``: camera -> (Camera, ``T_cam_field``), the first
    the primary (images without a camera name); ``input_hw``: the detector input (h, w) px = the window size;
    ``max_windows``: per frame (None: :func:`auto_windows` per frame size). Counts what it did (:meth:`summary`)."""

    def __init__(self, views: dict, input_hw: tuple[int, int], max_windows: int | None = None, far_px: float = FAR_PX, robot_height_m: float = ROBOT_HEIGHT_M):
        self.views = dict(views)
        self.primary = next(iter(self.views))
        self.input_hw = (int(input_hw[0]), int(input_hw[1]))
        self.max_windows = max_windows
        self.far_px, self.robot_height_m = float(far_px), float(robot_height_m)
        self._targets: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._lock = threading.Lock()
        self.frames = self.windows_run = self.boxes_added = 0

    @classmethod
    def for_pipeline(cls, pipeline, input_hw: tuple[int, int], max_windows: int | None = None) -> "FarWindows":
        """The cameras of a :class:`radarcal.runtime.pipeline.Pipeline`."""
        return cls({n: (v.camera, v.T_cam_field) for n, v in pipeline.views.items()}, input_hw, max_windows)

    def count(self, frame_hw: tuple[int, int]) -> int:
        """Windows per frame of ``frame_hw`` (h, w) px."""
        return auto_windows(frame_hw, self.input_hw) if self.max_windows is None else max(int(self.max_windows), 0)

    def active(self) -> bool:
        """Any camera of the bundle gets windows (its image size)."""
        return any(self.count(cam.image_size[::-1]) > 0 for cam, _T in self.views.values())

    def observe(self, _n: int, res) -> None:
        """After a frame (``on_frame`` callback): every output entry of ``res`` (a FrameResult) projected into each
        camera: image point (centre of the expected box) and expected box height (px, native)."""
        P = np.array([r.p_field for r in res.robots], float).reshape(-1, 3)
        head = P + np.array([0.0, 0.0, self.robot_height_m])
        targets = {}
        for name, (cam, T_cam_field) in self.views.items():
            uv_foot, ok_foot, _ = cam.project_from(T_cam_field, P)
            uv_head, ok_head, _ = cam.project_from(T_cam_field, head)
            uv = 0.5 * (uv_foot + uv_head)
            ok = ok_foot & ok_head & cam.in_image(uv)
            targets[name] = (uv[ok], np.abs(uv_foot[ok, 1] - uv_head[ok, 1]))
        self._targets = targets  # one assignment: the detect workers see the old or the new dict, never half of it

    def windows(self, camera: str | None, frame_hw: tuple[int, int]) -> np.ndarray:
        """(K,4) xyxy windows for a frame of ``camera`` (None: the primary) of ``frame_hw`` (h, w) px: around the
        targets whose expected box height at the full-frame letterbox scale is below ``far_px``, smallest first."""
        k = self.count(frame_hw)
        uv, h = self._targets.get(camera or self.primary, (np.zeros((0, 2)), np.zeros(0)))
        if k == 0 or not len(uv):
            return np.zeros((0, 4))
        scale = min(self.input_hw[0] / frame_hw[0], self.input_hw[1] / frame_hw[1], 1.0)
        far = h * scale < self.far_px
        order = np.argsort(h[far], kind="stable")
        return plan_rois(uv[far][order], frame_hw, self.input_hw, max_rois=k)

    def detect(self, detector, images: list, found: list[list], cameras: list[str] | None = None) -> list[list]:
        """Per image: its full-frame boxes ``found`` merged with ``detector.detect_regions`` on its windows."""
        out = []
        for i, (img, dets) in enumerate(zip(images, found)):
            win = self.windows(cameras[i] if cameras else None, img.shape[:2])
            if not len(win):
                out.append(dets)
                continue
            merged = detector.detect_regions(img, win, full=dets)
            with self._lock:
                self.frames += 1
                self.windows_run += len(win)
                self.boxes_added += max(len(merged) - len(dets), 0)
            out.append(merged)
        return out

    def summary(self) -> dict:
        """What the windows did: per-frame setting, camera frames with windows, windows run, boxes added."""
        return {"max_windows": "auto" if self.max_windows is None else int(self.max_windows), "far_px": self.far_px, "input": list(self.input_hw),
                "frames_with_windows": self.frames, "windows_run": self.windows_run, "boxes_added": self.boxes_added}  # fmt: skip

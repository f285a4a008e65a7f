"""Detector stages inside ``radarcal run``: a YOLOv8n-sized 640 robot detector + a 64 px number classifier on 12
crops per frame, through the whole loop on the sample replay, with the per-stage table and onnxruntime threads.

    PYTHONPATH=$PWD python -m benchmarks detector            # ~2-3 min on 2 busy cores
    PYTHONPATH=$PWD python -m benchmarks.detector --frames 150

No trained weights can be downloaded here: the graphs are generated with random weights at the real sizes
(``radarcal.runtime.synthetic_onnx``: YOLOv8n-like 4.05 GMAC / 3.0 M parameters at nc = 12, a 64 px grey CNN of
27 MMAC per crop, a YOLOv8n-like armour detector at 192 px). The random robot detector finds nothing, so the boxes
handed to the later stages are the replay's six detections per frame plus six more boxes beside them (12 crops);
every network still runs in full on every frame. Loop: JPEG decode in the prefetch thread, letterbox, onnxruntime
(worker threads sleep instead of spinning), decode + NMS, crops, classifier, fusion, tracks, JSON lines.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "datasets" / "sample_replay"
NAMES = [f"{t}_{n}" for t in ("red", "blue") for n in (1, 2, 3, 4, 5, 7)]


class _ReplayBoxes:
    """Runs the real robot detector on every frame (timed with the robot stage), then hands the replay's boxes of
    that frame plus as many shifted copies as needed to reach ``n_boxes`` to the later stages."""

    def __init__(self, detector, dfile, n_boxes: int):
        self.det, self.dfile, self.n = detector, dfile, n_boxes
        self.frame = None
        self.found = 0

    def detect_batch(self, images):
        out = []
        for found in self.det.detect_batch(images):
            self.found += len(found)
            boxes = list(self.dfile.lookup(self.frame[0], self.frame[1]))
            k = 0
            while boxes and len(boxes) < self.n:
                src = boxes[k % len(boxes)]
                from radarcal.runtime.detector import Detection

                w = src.xyxy[2] - src.xyxy[0]
                boxes.append(Detection(src.xyxy + np.array([w * 1.1, 0, w * 1.1, 0]), f"extra_{k}", src.score))
                k += 1
            out.append(boxes[: self.n])
        return out


def bench(frames: int = 120, threads: tuple[int, int] = (2, 2), armour: bool = False, crops: int = 12, spin: bool = False) -> dict:
    from radarcal.bundle import load_bundle
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector
    from radarcal.runtime.loop import Pipeline, RunConfig, run
    from radarcal.runtime.sources import CameraFrame, merge_by_time, open_replay, prefetch_frames
    from radarcal.runtime.stages import NumberClassifier, Recogniser
    from radarcal.runtime.synthetic_onnx import make_number_classifier, make_yolov8n_like

    b = load_bundle(SAMPLE / "calib.yaml")
    rep = open_replay(SAMPLE)
    dfile = DetectionsFile.read(rep.detections)
    with tempfile.TemporaryDirectory() as tmp:
        robot_p, num_p, arm_p = Path(tmp) / "robot.onnx", Path(tmp) / "number.onnx", Path(tmp) / "armour.onnx"
        st_robot = make_yolov8n_like(robot_p, nc=len(NAMES), names=NAMES)
        st_num = make_number_classifier(num_p, nc=9)
        st_arm = make_yolov8n_like(arm_p, nc=3, input_size=192, names=["blue", "red", "dead"], dynamic_batch=True, seed=1) if armour else None
        robot = OnnxDetector(robot_p, threads=threads[0], spin=spin)
        shim = _ReplayBoxes(robot, dfile, crops)
        arm = OnnxDetector(arm_p, threads=threads[1], spin=spin, conf_thres=0.0) if armour else None  # conf 0: every crop yields an armour box
        if arm is not None:
            arm.layout.nc = 3
        number = NumberClassifier(num_p, threads=threads[1], spin=spin)
        rec = Recogniser(shim, arm, number, number_conf=0.0)
        period = (rep.timeline[-1][0] if rep.timeline else rep.frames[-1][0]) + 1 / 30

        def cycled_frames():
            k = 0
            while True:
                for f in rep.camera_frames(need_pixels=True):
                    yield CameraFrame(f.t + k * period, f.name, f.load, f.index)
                k += 1

        def cycled_clouds():
            k = 0
            while True:
                for c in rep.cloud_frames():
                    c.t += k * period
                    yield c
                k += 1

        n_crops = []

        class Detect:
            last_timings_ms: dict = {}

            def __call__(self, f):
                shim.frame = (f.t % period, f.name)
                out = rec(f.load())
                Detect.last_timings_ms = rec.last_timings_ms
                n_crops.append(len(out))
                return [d for d in out if not d.label.startswith("extra_")]

        detect = Detect()
        img0 = next(rep.camera_frames(need_pixels=True)).load()
        shim.frame = (0.0, "000000.jpg")
        for _ in range(3):  # warm-up
            rec(img0)
        pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))
        cpu0, t0 = time.process_time(), time.perf_counter()
        load0 = os.getloadavg()[0]
        s = run(pipe, merge_by_time(prefetch_frames(cycled_frames()), cycled_clouds()), detect, out_path=Path(tmp) / "o.jsonl", status=False, max_frames=frames)
        cpu = time.process_time() - cpu0
        # baseline in the same process: the robot detector alone on the same image, no loop
        tic = time.perf_counter()
        for _ in range(20):
            robot(img0)
        alone_ms = (time.perf_counter() - tic) / 20 * 1e3
    return {"frames": s["frames"], "fps": s["fps"], "wall_s": time.perf_counter() - t0, "cpu_ms_per_frame": cpu / s["frames"] * 1e3,
            "stages": s["latency_ms"], "crops_per_frame": float(np.median(n_crops)), "robot_alone_ms": alone_ms, "robot_found": shim.found,
            "load": (load0 + os.getloadavg()[0]) / 2, "robot_stats": st_robot, "number_stats": st_num, "armour_stats": st_arm, "threads": threads,
            "armour": armour}  # fmt: skip


def _print(r: dict) -> None:
    rs, ns = r["robot_stats"], r["number_stats"]
    cfg = f"robot 640 ({rs['macs'] / 1e9:.2f} GMAC, {rs['params'] / 1e6:.2f} M) + "
    if r["armour"]:
        a = r["armour_stats"]
        cfg += f"armour 192 ({a['macs'] / 1e9:.2f} GMAC/crop) + "
    cfg += f"number 64 px ({ns['macs'] / 1e6:.0f} MMAC/crop) on {r['crops_per_frame']:.0f} crops; intra-op threads robot {r['threads'][0]}, later stages {r['threads'][1]}"
    print(cfg)
    print(f"  {r['frames']} frames, {r['fps']:.1f} FPS wall-clock; CPU {r['cpu_ms_per_frame']:.1f} ms per frame (all threads); "
          f"robot detector alone {r['robot_alone_ms']:.1f} ms; 1-min load average {r['load']:.1f} on {os.cpu_count()} cores")  # fmt: skip
    keys = ["cloud", "detect", "detect_robot", "detect_armour", "detect_number", "depth", "localise", "track", "output"]
    print("  " + " | ".join(f"{k:>13}" for k in ["stage ms"] + [k for k in keys if k in r["stages"]]))
    for q in ("median", "p95"):
        print("  " + " | ".join([f"{q:>13}"] + [f"{r['stages'][k][q]:>13.2f}" for k in keys if k in r["stages"]]))
    sys.stdout.flush()


def main(argv: list[str]) -> int:
    if not (SAMPLE / "meta.json").is_file():
        print(f"{SAMPLE} missing: run python datasets/make_sample.py")
        return 1
    frames = int(argv[argv.index("--frames") + 1]) if "--frames" in argv else 120
    print("detector stages in the whole loop (generated random-weight graphs of the real sizes; sample replay)\n")
    _print(bench(frames, (2, 2)))
    _print(bench(frames, (2, 1)))
    if "--no-armour" not in argv:
        _print(bench(max(frames // 3, 20), (2, 2), armour=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

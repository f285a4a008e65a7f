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
    that frame plus shifted copies up to ``n_boxes`` to the later stages (found by the decoded image's identity)."""

    def __init__(self, detector, n_boxes: int):
        self.det, self.n = detector, n_boxes
        self.by_image: dict[int, list] = {}
        self.found = 0

    def detect_batch(self, images):
        from radarcal.runtime.detector import Detection

        out = []
        for img, found in zip(images, self.det.detect_batch(images)):
            self.found += len(found)
            boxes = list(self.by_image.pop(id(img), []))
            k, base = 0, len(boxes)
            while base and len(boxes) < self.n:
                src = boxes[k % base]
                w = src.xyxy[2] - src.xyxy[0]
                boxes.append(Detection(src.xyxy + np.array([w * 1.1, 0, w * 1.1, 0]), f"extra_{k}", src.score))
                k += 1
            out.append(boxes[: self.n])
        return out


def bench(frames: int = 120, threads: tuple[int, int] = (2, 2), armour: bool = False, crops: int = 12, ahead: bool = True, spin: bool = False,
          workers: int = 1, prep: bool = False, camera_hz: float = 15.0) -> dict:  # fmt: skip
    from radarcal.bundle import load_bundle
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector
    from radarcal.runtime.loop import Pipeline, RunConfig, run
    from radarcal.runtime.sources import CameraFrame, merge_by_time, open_replay, prefetch_frames
    from radarcal.runtime.stages import DetectAhead, NumberClassifier, Recogniser
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
        shim = _ReplayBoxes(robot, crops)
        arm = OnnxDetector(arm_p, threads=threads[1], spin=spin, conf_thres=0.0) if armour else None  # conf 0: every crop yields an armour box
        number = NumberClassifier(num_p, threads=threads[1], spin=spin)
        rec = Recogniser(shim, arm, number, number_conf=0.0)
        n_crops = []

        def decode_and_register(f, t0):
            img = f.load()
            shim.by_image[id(img)] = dfile.lookup(t0, f.name)
            if prep:  # letterbox + tensor here, in the prefetch thread
                robot.prepare_ahead(img)
            return img

        # the replay keeps an image every 10th camera frame (3 images/s against 10 clouds/s): re-timed here to the
        # rates of a station, camera frames at ``camera_hz`` and clouds at 10 Hz, so that a frame carries the share
        # of cloud work a live run gives it (0.67 clouds per frame at 15 FPS, not the replay's 3.3)
        def cycled_frames():
            n = 0
            while True:
                for f in rep.camera_frames(need_pixels=True):
                    yield CameraFrame(n / camera_hz, f.name, (lambda f=f: decode_and_register(f, f.t)), n)
                    n += 1

        def cycled_clouds():
            m = 0
            while True:
                for c in rep.cloud_frames():
                    c.t = m / 10.0
                    yield c
                    m += 1

        class Detect(DetectAhead):
            def __call__(self, frame):
                out = super().__call__(frame)
                n_crops.append(len(out))
                return [d for d in out if not d.label.startswith("extra_")]

        detect = Detect(rec, workers=workers)
        f0 = next(cycled_frames())
        for _ in range(3):  # warm-up
            rec(f0.load())
        pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))
        src = prefetch_frames(cycled_frames())
        if ahead:
            src = detect.frames(src)
        load0 = os.getloadavg()[0]
        cpu0, t0 = time.process_time(), time.perf_counter()
        s = run(pipe, merge_by_time(src, cycled_clouds()), detect, out_path=Path(tmp) / "o.jsonl", status=False, max_frames=frames)
        cpu = time.process_time() - cpu0
        wall = time.perf_counter() - t0
        load = (load0 + os.getloadavg()[0]) / 2
        # baseline in the same process: the robot detector alone on one image, no loop
        img0 = f0.load()
        tic, c0 = time.perf_counter(), time.process_time()
        for _ in range(10):
            robot(img0)
        alone_ms = (time.perf_counter() - tic) / 10 * 1e3
        alone_cpu = (time.process_time() - c0) / 10 * 1e3
    return {"frames": s["frames"], "fps": s["fps"], "wall_s": wall, "cpu_ms_per_frame": cpu / s["frames"] * 1e3,
            "stages": s["latency_ms"], "crops_per_frame": float(np.median(n_crops)), "robot_alone_ms": alone_ms, "robot_alone_cpu_ms": alone_cpu, "robot_found": shim.found,
            "load": load, "robot_stats": st_robot, "number_stats": st_num, "armour_stats": st_arm, "threads": threads,
            "armour": armour, "ahead": ahead, "workers": workers, "prep": prep}  # fmt: skip


def _print(r: dict) -> None:
    rs, ns = r["robot_stats"], r["number_stats"]
    cfg = f"robot 640 ({rs['macs'] / 1e9:.2f} GMAC, {rs['params'] / 1e6:.2f} M) + "
    if r["armour"]:
        a = r["armour_stats"]
        cfg += f"armour 192 ({a['macs'] / 1e9:.2f} GMAC/crop) + "
    cfg += (f"number 64 px ({ns['macs'] / 1e6:.0f} MMAC/crop) on {r['crops_per_frame']:.0f} crops; intra-op threads robot {r['threads'][0]}, "
            f"later stages {r['threads'][1]}; {(str(r['workers']) + ' detect-ahead workers') if r['ahead'] else 'sequential'}"
            f"{'; letterbox in the prefetch thread' if r['prep'] else ''}")
    print(cfg)
    print(f"  {r['frames']} frames, {r['fps']:.1f} FPS wall-clock; CPU {r['cpu_ms_per_frame']:.1f} ms per frame (all threads); "
          f"1-min load average {r['load']:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(f"  baseline, same process: the robot detector alone (letterbox + onnxruntime + decode) {r['robot_alone_ms']:.1f} ms wall, "
          f"{r['robot_alone_cpu_ms']:.1f} ms CPU -> the whole loop costs {r['cpu_ms_per_frame'] / r['robot_alone_cpu_ms']:.2f}x its CPU time")  # fmt: skip
    c = r["cpu_ms_per_frame"]
    print(f"  CPU-time bounds: {1000 / c:.1f} FPS if all this CPU time ran on ONE free core, at most {2000 / c:.1f} FPS on two free cores")
    keys = ["cloud", "detect", "detect_robot", "detect_armour", "detect_number", "depth", "localise", "track", "output"]
    print("  (with the detect-ahead thread, `detect` is the loop's wait for the worker; detect_* are the stage times in the worker)" if r["ahead"] else "", end="\n" if r["ahead"] else "")
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
    _print(bench(frames, (2, 2), ahead=False))
    _print(bench(frames, (2, 2), ahead=True))
    _print(bench(frames, (1, 1), ahead=True))
    _print(bench(frames, (1, 1), ahead=True, workers=2))
    _print(bench(frames, (1, 1), ahead=True, workers=2, prep=True))
    if "--no-armour" not in argv:
        _print(bench(max(frames // 3, 20), (2, 2), armour=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

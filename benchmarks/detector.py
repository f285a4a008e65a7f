"""Detector stages inside ``radarcal run``: a YOLOv8n-sized 640 robot detector + a 64 px number classifier on 12
crops per frame, through the whole loop on the sample replay, with the per-stage table and onnxruntime threads.

    PYTHONPATH=$PWD python -m benchmarks detector            # 1 min 40 s on 2 quiet cores
    PYTHONPATH=$PWD python -m benchmarks.detector --frames 150

No trained weights can be downloaded here: the graphs are generated with random weights at the real sizes
(``radarcal.runtime.synthetic_onnx``: YOLOv8n-like 4.05 GMAC / 3.0 M parameters at nc = 12, a 64 px grey CNN of
27 MMAC per crop, a YOLOv8n-like armour detector at 192 px). The random robot detector finds nothing, so the boxes
handed to the later stages are the replay's six detections per frame plus six more boxes beside them (12 crops);
every network still runs in full on every frame. Loop: JPEG decode and letterbox in the prefetch thread, inference
(onnxruntime with sleeping worker threads, or ``--providers openvino``), decode + NMS, crops, classifier, fusion,
tracks, JSON lines. Rows: float and int8 (``radarcal quantise``) models on onnxruntime and on OpenVINO (skipped with
a line when the openvino package is absent), two thread layouts, and the armour stage.
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


def bench(frames: int = 120, threads: int = 1, workers: int = 2, providers: str = "cpu", int8: bool | str = False, armour: bool = False, crops: int = 12,
          ahead: bool = True, prep: bool = True, camera_hz: float = 15.0, models: dict | None = None) -> dict:  # fmt: skip
    """One configuration of ``radarcal run --detector robot.onnx --number number.onnx [--armour armour.onnx]
    --providers P --threads T --detect-workers W``: the detector is built by ``match_run.open_detector`` from those
    options (what the CLI builds), frames are decoded (and, ``prep``, letterboxed) in the prefetch thread as
    ``radarcal run`` does. ``int8``: the models ``radarcal quantise`` wrote instead of the float ones (``"sym"``:
    with ``--activations int8``)."""
    from radarcal.bundle import load_bundle
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.loop import Pipeline, RunConfig, run
    from radarcal.runtime.match_run import RunOptions, open_detector
    from radarcal.runtime.sources import CameraFrame, merge_by_time, open_replay, prefetch_frames

    b = load_bundle(SAMPLE / "calib.yaml")
    rep = open_replay(SAMPLE)
    dfile = DetectionsFile.read(rep.detections)
    m = models["int8s" if int8 == "sym" else "int8" if int8 else "fp32"]
    with tempfile.TemporaryDirectory() as tmp:
        opts = RunOptions(detector=m["robot"], number=m["number"], armour=m["armour"] if armour else None, providers=providers, threads=threads,
                          detect_workers=workers, detect_ahead=ahead, conf=0.25)  # fmt: skip
        notes = []
        detect = open_detector(opts, notes.append)
        rec = detect.recogniser
        robot = rec.robot
        shim = _ReplayBoxes(robot, crops)
        rec.robot = shim
        if rec.armour is not None:
            rec.armour.conf_thres = 0.0  # every crop yields an armour box, so the number stage always runs
        rec.number_conf = 0.0
        n_crops = []

        def decode_and_register(f, t0):
            img = f.load()
            shim.by_image[id(img)] = dfile.lookup(t0, f.name)
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
            k = 0
            while True:
                for c in rep.cloud_frames():
                    c.t = k / 10.0
                    yield c
                    k += 1

        inner_run = detect._run

        def counted_run(frame):
            dets, tm = inner_run(frame)
            n_crops.append(len(dets))
            return [d for d in dets if not d.label.startswith("extra_")], tm

        detect._run = counted_run
        f0 = next(cycled_frames())
        for _ in range(3):  # warm-up (OpenVINO compiles shape-specific kernels on the first calls)
            rec(f0.load())
        pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))
        src = prefetch_frames(cycled_frames(), prepare=detect.prepare_ahead if prep else None)  # as match_run does
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
        desc = robot.describe()
    return {"frames": s["frames"], "fps": s["fps"], "wall_s": wall, "cpu_ms_per_frame": cpu / s["frames"] * 1e3,
            "stages": s["latency_ms"], "crops_per_frame": float(np.median(n_crops)), "robot_alone_ms": alone_ms, "robot_alone_cpu_ms": alone_cpu, "robot_found": shim.found,
            "load": load, "robot_stats": models["stats"]["robot"], "number_stats": models["stats"]["number"], "armour_stats": models["stats"]["armour"],
            "threads": threads, "providers": providers, "int8": int8, "desc": desc,
            "armour": armour, "ahead": ahead, "workers": workers, "prep": prep}  # fmt: skip


def make_models(root: Path, armour: bool = True, int8: bool = True) -> dict:
    """The random-weight graphs of the real sizes, and (``int8``) their int8 copies written by ``radarcal quantise``
    (calibrated on the sample replay's frames)."""
    from radarcal.runtime.synthetic_onnx import make_number_classifier, make_yolov8n_like

    fp = {"robot": root / "robot.onnx", "number": root / "number.onnx", "armour": root / "armour.onnx"}
    stats = {"robot": make_yolov8n_like(fp["robot"], nc=len(NAMES), names=NAMES), "number": make_number_classifier(fp["number"], nc=9), "armour": None}
    if armour:
        stats["armour"] = make_yolov8n_like(fp["armour"], nc=3, input_size=192, names=["blue", "red", "dead"], dynamic_batch=True, seed=1)
    out = {"fp32": fp, "stats": stats}
    if int8:
        from radarcal.runtime.quantise import quantise_model

        images = sorted((SAMPLE / "images").glob("*.jpg"))
        q = {k: root / f"{k}.int8.onnx" for k in ("robot", "number")}
        out["quantise"] = {k: quantise_model(fp[k], q[k], images[:16], held_out=images[16:20]) for k in q}
        out["int8"] = dict(fp, **q)
        # symmetric int8 activations (--activations int8): what OpenVINO runs fastest
        qs = {k: root / f"{k}.int8s.onnx" for k in ("robot", "number")}
        out["quantise"].update({f"{k} (--activations int8)": quantise_model(fp[k], qs[k], images[:16], held_out=images[16:20], activations="int8") for k in qs})
        out["int8s"] = dict(fp, **qs)
    return out


def _print(r: dict) -> None:
    rs, ns = r["robot_stats"], r["number_stats"]
    flags = f"--providers {r['providers']} --threads {r['threads']} --detect-workers {r['workers']}" + ("" if r["ahead"] else " --no-detect-ahead")
    q = {"sym": " (int8 models from radarcal quantise --activations int8)", True: " (int8 models from radarcal quantise)", False: ""}[r["int8"]]
    cfg = f"`{flags}`{q}: robot 640 ({rs['macs'] / 1e9:.2f} GMAC, {rs['params'] / 1e6:.2f} M) + "
    if r["armour"]:
        a = r["armour_stats"]
        cfg += f"armour 192 ({a['macs'] / 1e9:.2f} GMAC/crop) + "
    cfg += f"number 64 px ({ns['macs'] / 1e6:.0f} MMAC/crop) on {r['crops_per_frame']:.0f} crops{'; letterbox in the prefetch thread' if r['prep'] else ''}"
    print(cfg)
    print(f"  robot detector: {r['desc']}")
    print(f"  {r['frames']} frames, {r['fps']:.1f} FPS wall-clock; CPU {r['cpu_ms_per_frame']:.1f} ms per frame (all threads); "
          f"1-min load average {r['load']:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(f"  baseline, same process: the robot detector alone (letterbox + inference + decode) {r['robot_alone_ms']:.1f} ms wall, "
          f"{r['robot_alone_cpu_ms']:.1f} ms CPU -> the whole loop costs {r['cpu_ms_per_frame'] / r['robot_alone_cpu_ms']:.2f}x its CPU time")  # fmt: skip
    c = r["cpu_ms_per_frame"]
    print(f"  CPU-time bounds: {1000 / c:.1f} FPS if all this CPU time ran on ONE free core, at most {2000 / c:.1f} FPS on two free cores")
    keys = ["cloud", "detect", "detect_robot", "detect_armour", "detect_number", "depth", "localise", "track", "output"]
    if r["ahead"]:
        print("  (with the detect-ahead thread, `detect` is the loop's wait for the worker; detect_* are the stage times in the worker)")
    print("  | stage ms | " + " | ".join(k for k in keys if k in r["stages"]) + " |")
    print("  |---|" + "---|" * len([k for k in keys if k in r["stages"]]))
    for q in ("median", "p95"):
        print(f"  | {q} | " + " | ".join(f"{r['stages'][k][q]:.2f}" for k in keys if k in r["stages"]) + " |")
    sys.stdout.flush()


def _print_quantise(q: dict) -> None:
    print("int8 copies (`radarcal quantise MODEL --images datasets/sample_replay/images -o MODEL.int8.onnx`, 16 calibration frames):")
    for k, v in q.items():
        print(f"  {k}: {v['quantised']} of {v['convs']} convolutions int8; float {v['ms_fp32']:.1f} ms -> int8 {v['ms_int8']:.1f} ms CPU per run "
              f"(onnxruntime, 1 thread, same process: {v['ms_int8'] / v['ms_fp32']:.2f}x)")  # fmt: skip
    print("  (random weights: their outputs hardly depend on the frame, so their agreement says nothing; it is measured below on a graph whose boxes come from the pixels)")
    sys.stdout.flush()


def square_agreement() -> dict:
    """Box agreement of an int8 copy with its float model and with the truth, on generated frames: the
    pixel-driven ``make_square_finder`` graph (24 px red / blue squares), calibrated on 8 frames, checked on 8 others."""
    from radarcal.runtime.detector import OnnxDetector
    from radarcal.runtime.quantise import quantise_model
    from radarcal.runtime.synthetic_onnx import make_square_finder

    rng = np.random.default_rng(5)

    def frame():
        img = rng.integers(40, 80, (480, 640, 3), dtype=np.uint8)
        truth = []
        for k in range(8):
            a, b = 4 * int(rng.integers(2, 150)), 4 * int(rng.integers(2, 110))
            if any(abs(a - x) < 64 and abs(b - y) < 64 for _, (x, y) in truth):
                continue
            img[b : b + 24, a : a + 24] = (0, 0, 255) if k % 2 == 0 else (255, 0, 0)
            truth.append(("red" if k % 2 == 0 else "blue", (a, b)))
        return img, truth

    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "sq.onnx", Path(tmp) / "sq.int8.onnx"
        make_square_finder(src, side=24)
        frames = [frame() for _ in range(16)]
        r = quantise_model(src, dst, [f for f, _ in frames[:8]], held_out=[f for f, _ in frames[8:]])
        det = OnnxDetector(dst, threads=1)
        err, n, hit = [], 0, 0
        for img, truth in frames[8:]:
            dets = det(img)
            for label, (a, b) in truth:
                n += 1
                box = np.array([a - 0.5, b - 0.5, a + 23.5, b + 23.5])
                cand = [np.abs(d.xyxy - box).max() for d in dets if d.label == label]
                if cand and min(cand) < 1.0:
                    hit += 1
                    err.append(min(cand))
    r["truth"] = {"squares": n, "found": hit, "max_px": float(max(err)) if err else float("nan")}
    return r


def _print_square(r: dict) -> None:
    a, t = r["agreement"], r["truth"]
    print(f"int8 vs float on generated frames (square-finder graph, {r['frames']} calibration + {r['held_out']} held-out frames): {a['boxes']} float boxes, "
          f"{100 * a['matched']:.0f} % found again by int8, IoU median {a['iou_median']:.4f} / min {a['iou_min']:.4f}, score difference median "
          f"{a['score_diff_median']:.4f} / max {a['score_diff_max']:.4f}, {a['extra']} extra; int8 vs truth: {t['found']} / {t['squares']} squares, "
          f"corners within {t['max_px']:.3f} px")  # fmt: skip
    sys.stdout.flush()


def main(argv: list[str]) -> int:
    if not (SAMPLE / "meta.json").is_file():
        print(f"{SAMPLE} missing: run python datasets/make_sample.py")
        return 1
    frames = int(argv[argv.index("--frames") + 1]) if "--frames" in argv else 120
    try:
        import openvino  # noqa: F401

        ov = True
    except ImportError:
        ov = False
        print("(openvino not installed: the --providers openvino rows are skipped; pip install openvino)")
    print("detector stages in the whole loop (generated random-weight graphs of the real sizes; sample replay)\n")
    with tempfile.TemporaryDirectory() as tmp:
        models = make_models(Path(tmp), armour="--no-armour" not in argv)
        _print_quantise(models["quantise"])
        _print_square(square_agreement())
        print()
        _print(bench(frames, threads=1, workers=2, models=models))  # the onnxruntime baseline (fastest float layout before)
        _print(bench(frames, threads=1, workers=2, int8=True, models=models))
        if ov:
            _print(bench(frames, threads=1, workers=2, providers="openvino", models=models))
            _print(bench(frames, threads=1, workers=2, providers="openvino", int8="sym", models=models))
            _print(bench(frames, threads=2, workers=1, providers="openvino", models=models))
        if "--no-armour" not in argv:
            _print(bench(max(frames // 3, 20), threads=1, workers=2, providers="openvino" if ov else "cpu", armour=True, models=models))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Several cameras and large frames (issue #19's benchmark): two 1280x1024 cameras with a YOLOv5n-size detector
each, and one 12 MP camera (4024x3036) with the full frame plus native-resolution regions of interest for far robots.

    PYTHONPATH=$PWD python -m benchmarks multicam_speed              # < 3 min on 2 quiet cores
    PYTHONPATH=$PWD python -m benchmarks.multicam_speed --frames 90 --only two|big|cli   # cli: through `radarcal run` (2 x 1280x1024; 12 MP with and without --roi-windows)

Per camera frame: the frame is made in a prefetch thread per camera (1280x1024: JPEG decode of the sample replay's
images, as a replay does; 12 MP: a raw Bayer BG8 frame demosaiced, as an industrial camera delivers it), letterboxed
into the detector's input there (``OnnxDetector.prepare_ahead``); two detect workers (one onnxruntime intra-op
thread each) run the detector (and, 12 MP, ``detect_regions`` on ``plan_rois`` windows around far robots); the
main thread fuses each frame's boxes (``Pipeline.process``, the sample replay's detections, because the random-weight
net finds nothing) and ingests a cloud every 0.1 s of frame time. No trained weights can be downloaded here: the
detector is ``synthetic_onnx.make_yolov5n_like`` (2.19 GMAC, 1.61 M parameters, YOLOv5n's 1 x 25200 x 17 output).

Two runs per configuration: *as fast as possible* (throughput: frames per second per camera, CPU time per frame of
all threads, the FPS that CPU time allows on two free cores) and *paced* at the target rate with the prefetch
keeping only the newest frame (``latest_only``, as for a live camera): frame age at the output (capture -> fused)
and frames dropped, which is what "no latency build-up" means.
"""

from __future__ import annotations

import os
import queue
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "datasets" / "sample_replay"
NAMES = [f"{t}_{n}" for t in ("red", "blue") for n in (1, 2, 3, 4, 5, 7)]
BIG_HW = (3036, 4024)


def _frames(kind: str, n: int) -> list:
    """Source frames: JPEG bytes of 1280x1024 images (``jpeg``, ``jpeg_flip`` for a second camera) or 12 MP Bayer BG8
    arrays (``bayer``)."""
    import cv2

    paths = sorted((SAMPLE / "images").glob("*.jpg"))[:n]
    out = []
    for p in paths:
        img = cv2.imread(str(p))
        if kind == "jpeg_flip":
            img = img[:, ::-1].copy()
        if kind.startswith("jpeg"):
            out.append((p.name, cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])[1]))
        else:
            big = cv2.resize(img, BIG_HW[::-1], interpolation=cv2.INTER_LINEAR)
            bayer = np.empty(BIG_HW, np.uint8)  # BG pattern: B at (even, even), R at (odd, odd)
            bayer[0::2, 0::2] = big[0::2, 0::2, 0]
            bayer[0::2, 1::2] = big[0::2, 1::2, 1]
            bayer[1::2, 0::2] = big[1::2, 0::2, 1]
            bayer[1::2, 1::2] = big[1::2, 1::2, 2]
            out.append((p.name, bayer))
    return out


class _Stream:
    """One camera. A capture thread hands over raw frames (JPEG bytes / Bayer arrays); ``paced_hz``: at that rate,
    into a one-frame slot that a newer capture overwrites (the older one is dropped before any work is spent on it, as
    a live camera driver does). A prefetch thread takes the newest raw frame, decodes / demosaics it and letterboxes
    it for the detector (``prepare_ahead``), and queues it (one frame when paced)."""

    def __init__(self, cam: str, src: list, detector, total: int, paced_hz: float | None):
        self.cam, self.src, self.det, self.total, self.hz = cam, src, detector, total, paced_hz
        self.raw: queue.Queue = queue.Queue(maxsize=1 if paced_hz else 3)
        self.q: queue.Queue = queue.Queue(maxsize=1 if paced_hz else 3)
        self.dropped = 0
        self.cpu = {"decode": [], "letterbox": []}
        self.wall = {"decode": [], "letterbox": []}
        self.lock = threading.Lock()
        self.th = [threading.Thread(target=self._capture, daemon=True), threading.Thread(target=self._prefetch, daemon=True)]

    def start(self):
        for t in self.th:
            t.start()

    def _capture(self):
        t_start = time.perf_counter()
        for k in range(self.total):
            if self.hz:
                wait = t_start + k / self.hz - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            name, data = self.src[k % len(self.src)]
            item = (k, name, data, time.perf_counter())
            if self.hz:
                with self.lock:
                    try:
                        self.raw.get_nowait()
                        self.dropped += 1
                    except queue.Empty:
                        pass
                    self.raw.put(item)
            else:
                self.raw.put(item)
        self.raw.put(None)

    def _prefetch(self):
        import cv2

        while True:
            item = self.raw.get()
            if item is None:
                break
            k, name, data, t_cap = item
            c0, w0 = time.thread_time(), time.perf_counter()
            img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.ndim == 1 else cv2.cvtColor(data, cv2.COLOR_BayerBG2BGR)
            c1, w1 = time.thread_time(), time.perf_counter()
            self.det.prepare_ahead(img)
            self.cpu["decode"].append(c1 - c0)
            self.wall["decode"].append(w1 - w0)
            self.cpu["letterbox"].append(time.thread_time() - c1)
            self.wall["letterbox"].append(time.perf_counter() - w1)
            self.q.put((k, name, img, t_cap))
        self.q.put(None)


def bench(kind: str = "two", frames: int = 90, paced_hz: float | None = None, rois: int = 2, workers: int = 2, providers: str = "cpu", threads: int = 1,
          roi_every: int = 1, batch_rois: bool = False) -> dict:  # fmt: skip
    """One configuration. ``paced_hz``: the capture delivers frames at that rate into a one-frame slot (drop-oldest:
    a newer frame replaces one nobody took yet), so the output rate is what the pipeline sustains and the frame age
    shows whether latency builds up; None: frames handed over as fast as they are taken (throughput).
    ``providers`` / ``threads``: as ``radarcal run --providers --threads`` (``OnnxDetector``). 12 MP: ``rois``
    windows every ``roi_every``-th frame; ``batch_rois``: a dynamic-batch export, all windows in one call."""
    from radarcal.bundle import load_bundle
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector, plan_rois
    from radarcal.runtime.loop import Pipeline, RunConfig, limit_blas_threads
    from radarcal.runtime.sources import open_replay
    from radarcal.runtime.synthetic_onnx import count_macs, make_yolov5n_like

    b = load_bundle(SAMPLE / "calib.yaml")
    rep = open_replay(SAMPLE)
    dfile = DetectionsFile.read(rep.detections)
    clouds = [c.points for c in rep.cloud_frames()][:30]
    cams = ["cam0", "cam1"] if kind == "two" else ["cam0"]
    srcs = {"cam0": _frames("jpeg", 30), "cam1": _frames("jpeg_flip", 30)} if kind == "two" else {"cam0": _frames("bayer", 6)}
    hz_target = 15.0 if kind == "two" else 10.0
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp, limit_blas_threads(1):
        dets, pipes = {}, {}
        for i, cam in enumerate(cams):
            make_yolov5n_like(Path(tmp) / f"{cam}.onnx", nc=len(NAMES), names=NAMES, seed=i, dynamic_batch=batch_rois)
            dets[cam] = OnnxDetector(Path(tmp) / f"{cam}.onnx", threads=threads, providers=providers, parallel=1)
            pipes[cam] = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))  # the fusion cost per camera frame
        warm = srcs["cam0"][0][1]
        import cv2

        wimg = cv2.imdecode(warm, cv2.IMREAD_COLOR) if warm.ndim == 1 else cv2.cvtColor(warm, cv2.COLOR_BayerBG2BGR)
        for d in dets.values():
            for _ in range(2):
                d(wimg)
        streams = {cam: _Stream(cam, srcs[cam], dets[cam], frames, paced_hz) for cam in cams}
        stage_cpu = {k: [] for k in ("detect", "regions", "fuse")}
        stage_wall = {k: [] for k in ("infer", "nms", "regions", "fuse")}
        ages, n_rois = [], []
        out_t: dict[str, list[float]] = {}

        def detect(cam, img, k_frame):
            c0 = time.thread_time()
            d = dets[cam]
            found = d.detect_batch([img])[0]
            tm = dict(d.last_timings_ms)
            c1 = time.thread_time()
            reg = None
            if kind == "big" and rois and k_frame % roi_every == 0:
                # far robots: the replay's smallest boxes stand in for far tracks projected into the frame (a
                # 12 MP frame is 3.14x the 1280x1024 the boxes are in)
                pts = np.array([[0.5 * (x.xyxy[0] + x.xyxy[2]), 0.5 * (x.xyxy[1] + x.xyxy[3])] for x in sorted(dfile.boxes[0], key=lambda x: x.xyxy[2] - x.xyxy[0])])
                pts = pts * (BIG_HW[1] / 1280.0) + rng.normal(0, 30, pts.shape)
                win = plan_rois(pts, img.shape[:2], 640, max_rois=rois)
                found = d.detect_regions(img, win, full=found)
                reg = dict(d.last_timings_ms)
            return found, tm, reg, c1 - c0, time.thread_time() - c1

        order = []  # (cam, future, frame index, name, t_capture)
        done = {cam: False for cam in cams}
        count = {cam: 0 for cam in cams}
        cloud_k = 0
        turn = 0
        load0 = os.getloadavg()[0]
        for s in streams.values():
            s.start()
        cpu0, t0 = time.process_time(), time.perf_counter()
        with ThreadPoolExecutor(workers, thread_name_prefix="detect") as ex:
            while not all(done.values()) or order:
                turn = (turn + 1) % len(cams)
                for cam in cams[turn:] + cams[:turn]:  # one frame of each camera in turn, starting with the next one
                    if done[cam] or len(order) >= workers:  # at most `workers` frames in flight: no queue builds up
                        continue
                    item = streams[cam].q.get()
                    if item is None:
                        done[cam] = True
                        continue
                    k, name, img, t_cap = item
                    order.append((cam, ex.submit(detect, cam, img, k), k, name, t_cap))
                if not order:
                    continue
                cam, fut, k, name, t_cap = order.pop(0)
                found, tm, reg, cpu_det, cpu_reg = fut.result()
                c0, w0 = time.thread_time(), time.perf_counter()
                t_frame = k / hz_target
                while cloud_k / 10.0 <= t_frame and cam == cams[0]:
                    pipes[cam].add_cloud(cloud_k / 10.0, clouds[cloud_k % len(clouds)])
                    cloud_k += 1
                pipes[cam].process(t_frame, name, dfile.lookup(0.0, name) if found is not None else [])
                stage_cpu["fuse"].append(time.thread_time() - c0)
                stage_wall["fuse"].append(time.perf_counter() - w0)
                stage_cpu["detect"].append(cpu_det)
                stage_cpu["regions"].append(cpu_reg)
                stage_wall["infer"].append(tm["infer"] / 1e3)
                stage_wall["nms"].append(tm["decode"] / 1e3)
                if reg is not None:
                    stage_wall["regions"].append((reg["preprocess"] + reg["infer"] + reg["decode"] + reg["merge"]) / 1e3)
                    n_rois.append(reg["regions"])
                ages.append(time.perf_counter() - t_cap)
                out_t.setdefault(cam, []).append(time.perf_counter())
                count[cam] += 1
        wall = time.perf_counter() - t0
        cpu = time.process_time() - cpu0
        load = 0.5 * (load0 + os.getloadavg()[0])
    n = sum(count.values())
    macs, params = count_macs(640, len(NAMES))
    dec = {k: np.concatenate([np.asarray(s.cpu[k]) for s in streams.values()]) for k in ("decode", "letterbox")}
    decw = {k: np.concatenate([np.asarray(s.wall[k]) for s in streams.values()]) for k in ("decode", "letterbox")}
    return {"kind": kind, "cams": cams, "wall_s": wall, "frames_per_cam": min(count.values()), "fps_per_cam": min((len(v) - 1) / max(v[-1] - v[0], 1e-9) for v in out_t.values()), "cpu_ms_per_frame": cpu / n * 1e3,
            "cpu_stage_ms": {"decode": 1e3 * np.median(dec["decode"]), "letterbox": 1e3 * np.median(dec["letterbox"]),
                             **{k: 1e3 * np.median(v) for k, v in stage_cpu.items()}},
            "wall_stage_ms": {"decode": (1e3 * np.median(decw["decode"]), 1e3 * np.percentile(decw["decode"], 95)),
                              "letterbox": (1e3 * np.median(decw["letterbox"]), 1e3 * np.percentile(decw["letterbox"], 95)),
                              **{k: (1e3 * np.median(v), 1e3 * np.percentile(v, 95)) for k, v in stage_wall.items() if v}},
            "age_ms": (1e3 * np.median(ages), 1e3 * np.percentile(ages, 95), 1e3 * np.max(ages)), "dropped": sum(s.dropped for s in streams.values()),
            "offered": frames * len(cams), "paced_hz": paced_hz, "load": load, "macs": macs, "params": params, "rois": float(np.median(n_rois)) if n_rois else 0.0,
            "hz_target": hz_target, "providers": providers, "threads": threads, "workers": workers, "roi_every": roi_every, "batch_rois": batch_rois,
            "desc": dets[cams[0]].describe()}  # fmt: skip


def _print(r: dict) -> None:
    what = "two 1280x1024 cameras (JPEG replay frames)" if r["kind"] == "two" else f"one 12 MP camera {BIG_HW[1]}x{BIG_HW[0]} (raw Bayer frames), full frame + {r['rois']:.0f} ROI windows"
    if r["kind"] == "big" and r["rois"]:
        what += (" every 2nd frame" if r["roi_every"] == 2 else f" every {r['roi_every']}th frame" if r["roi_every"] > 2 else "") + (" in one batched call" if r["batch_rois"] else "")
    mode = f"camera delivering {r['paced_hz']:.0f} FPS, newest frame only (drop-oldest)" if r["paced_hz"] else "frames as fast as they are taken"
    c = r["cpu_ms_per_frame"]
    print(f"{what}; `--providers {r['providers']} --threads {r['threads']}`, {r['workers']} detect workers; {mode}")
    print(f"  detector: {r['desc']}, YOLOv5n-size {r['macs'] / 1e9:.2f} GMAC per 640 run")
    print(f"  {r['frames_per_cam']} frames per camera out: {r['fps_per_cam']:.1f} FPS per camera wall-clock (first to last output); CPU {c:.1f} ms per camera frame (all threads) -> "
          f"{2000 / c / len(r['cams']):.1f} FPS per camera on two free cores; frame age capture->fused median {r['age_ms'][0]:.0f} ms, p95 {r['age_ms'][1]:.0f}, "
          f"max {r['age_ms'][2]:.0f}; dropped {r['dropped']} / {r['offered']}; 1-min load average {r['load']:.1f} on {os.cpu_count()} cores")  # fmt: skip
    keys = [k for k in ("decode", "letterbox", "infer", "nms", "regions", "fuse") if k in r["wall_stage_ms"]]
    cpu_of = {"decode": "decode", "letterbox": "letterbox", "infer": "detect", "nms": None, "regions": "regions", "fuse": "fuse"}
    print("  | stage | " + " | ".join(keys) + " |")
    print("  |---|" + "---|" * len(keys))
    print("  | wall median / p95 (ms) | " + " | ".join(f"{r['wall_stage_ms'][k][0]:.1f} / {r['wall_stage_ms'][k][1]:.1f}" for k in keys) + " |")
    ov = r["desc"].split(", ")[-1].startswith("OpenVINO")  # its inference runs in its own stream threads: not in the caller's thread time

    def cpu(k):
        if cpu_of[k] is None:
            return "(in infer)"
        if ov and k in ("infer", "regions"):
            return "(OpenVINO threads)"
        return f"{r['cpu_stage_ms'][cpu_of[k]]:.1f}"

    print("  | CPU median (ms) | " + " | ".join(cpu(k) for k in keys) + " |")
    sys.stdout.flush()


def run_cli_two_cameras(frames: int, providers: str, threads: int = 0) -> dict:
    """The real thing: ``radarcal synth field --cameras cam0=6mm,cam1=16mm`` (1280x1024 each), then ``radarcal run
    --replay R --detector v5n.onnx --providers P --threads T --speed 0`` (unpaced: throughput) as a subprocess;
    its JSON summary (frames = camera ticks, each with both cameras)."""
    import json
    import subprocess

    from radarcal.runtime.synthetic_onnx import make_yolov5n_like

    py = [sys.executable, "-m", "radarcal"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        rep, model = Path(tmp) / "two", Path(tmp) / "v5n.onnx"
        subprocess.run(py + ["synth", "field", str(rep), "--frames", str(frames), "--cameras", "cam0=6mm,cam1=16mm", "--json"], check=True, capture_output=True, env=env)
        make_yolov5n_like(model, nc=len(NAMES), names=NAMES)
        cmd = ["run", "--replay", str(rep), "--detector", str(model), "--providers", providers, "--threads", str(threads), "--speed", "0", "--json", "--quiet",
               "--out", str(Path(tmp) / "o.jsonl")]  # fmt: skip
        p = subprocess.run(py + cmd, capture_output=True, text=True, env=env)
        if p.returncode != 0:
            raise RuntimeError(p.stderr)
        out = json.loads(p.stdout)
        out["cmd"] = "radarcal " + " ".join(c if not c.startswith(tmp) else c.replace(tmp, "$TMP") for c in cmd)
        return out


def big_replay(root: Path, frames: int) -> Path:
    """``synth field --cameras cam0=8mm:4024x3036`` with its JPEGs rewritten as BMP (uncompressed, as a 12 MP replay
    should be recorded: a 12 MP JPEG costs ~150 ms of CPU to decode); made once per ``root``."""
    import subprocess

    import cv2

    rep = root / f"multicam_speed_12mp_{frames}"
    images = rep / "cameras" / "cam0" / "images"
    if (rep / "meta.json").is_file() and not list(images.glob("*.jpg")):
        return rep
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-m", "radarcal", "synth", "field", str(rep), "--frames", str(frames), "--cameras", f"cam0=8mm:{BIG_HW[1]}x{BIG_HW[0]}", "--overwrite", "--json"],
                   check=True, capture_output=True, env=env)  # fmt: skip
    for p in sorted(images.glob("*.jpg")):
        cv2.imwrite(str(p.with_suffix(".bmp")), cv2.imread(str(p)))
        p.unlink()
    times = images / "times.csv"
    times.write_text(times.read_text().replace(".jpg,", ".bmp,"))
    return rep


def run_cli_big(frames: int, providers: str, windows: int, threads: int = 1, workers: int = 2) -> dict:
    """One 12 MP camera through ``radarcal run`` itself: :func:`big_replay` (kept in ``$RADARCAL_BENCH_CACHE`` when
    set, else in memory), then ``run --replay R --detector v5n.onnx --roi-windows K --speed 0`` (the run places
    the windows around its far tracks). Its JSON summary (``roi_windows``: what the windows did)."""
    import json
    import subprocess

    from radarcal.runtime.synthetic_onnx import make_yolov5n_like

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cache = os.environ.get("RADARCAL_BENCH_CACHE")
    with tempfile.TemporaryDirectory(dir="/dev/shm" if os.path.isdir("/dev/shm") else None) as tmp:  # 36 MB per frame: in memory
        rep, model = big_replay(Path(cache) if cache else Path(tmp), frames), Path(tmp) / "v5n.onnx"
        make_yolov5n_like(model, nc=len(NAMES), names=NAMES)
        cmd = ["run", "--replay", str(rep), "--detector", str(model), "--providers", providers, "--threads", str(threads), "--detect-workers", str(workers), "--roi-windows", str(windows), "--speed", "0",
               "--json", "--quiet", "--out", str(Path(tmp) / "o.jsonl")]  # fmt: skip
        p = subprocess.run([sys.executable, "-m", "radarcal"] + cmd, capture_output=True, text=True, env=env)
        if p.returncode != 0:
            raise RuntimeError(p.stderr)
        out = json.loads(p.stdout)
        out["cmd"] = "radarcal " + " ".join(c.replace(tmp, "$TMP").replace(str(rep), "$REPLAY") for c in cmd)
        out["what"] = f"one 12 MP camera {BIG_HW[1]}x{BIG_HW[0]}, generated replay as BMP"
        out["load"] = os.getloadavg()[0]
        return out


def _print_cli(s: dict) -> None:
    lat = s["latency_ms"]
    what = s.get("what", "two 1280x1024 cameras, generated replay")
    print(f"`{s['cmd']}` ({what}; 1-min load average {s.get('load', os.getloadavg()[0]):.1f}):")
    print(f"  {s['frames']} ticks ({', '.join(s.get('cameras') or [s['camera']])} each) in {s['wall_s']:.1f} s: {s['fps']:.1f} FPS per camera, end to end")
    if s.get("roi_windows"):
        rw = s["roi_windows"]
        print(f"  far-robot windows: {rw['windows_run']} windows on {rw['frames_with_windows']} frames ({rw['windows_run'] / max(s['frames'], 1):.2f} per frame), {rw['boxes_added']} boxes added")
    print("  | stage ms | " + " | ".join(lat) + " |")
    print("  |---|" + "---|" * len(lat))
    for q in ("median", "p95"):
        print(f"  | {q} | " + " | ".join(f"{v[q]:.1f}" for v in lat.values()) + " |")
    sys.stdout.flush()


def main(argv: list[str]) -> int:
    if not (SAMPLE / "meta.json").is_file():
        print(f"{SAMPLE} missing: run python datasets/make_sample.py")
        return 1
    frames = int(argv[argv.index("--frames") + 1]) if "--frames" in argv else 90
    only = argv[argv.index("--only") + 1] if "--only" in argv else None
    try:
        import openvino  # noqa: F401

        fast = "openvino"
    except ImportError:
        fast = "cpu"
        print("(openvino not installed: the --providers openvino rows run on onnxruntime; pip install openvino)")
    print("cameras x detector throughput (random-weight YOLOv5n-size graph; detect = letterboxed run + decode + NMS; CPU = thread time)")
    print("(detect CPU: the full frame's inference + decode + NMS; regions: the ROI windows' letterbox + run + decode + merge)\n")
    big = max(frames * 2 // 3, 20)
    if only in (None, "two"):
        # paced rows: the camera delivers twice the frames at twice the target rate (same duration as the target run)
        _print(bench("two", 2 * frames, paced_hz=30.0))  # the onnxruntime baseline
        _print(bench("two", frames, providers=fast))
        _print(bench("two", 2 * frames, paced_hz=30.0, providers=fast))
    if only in (None, "big"):
        _print(bench("big", big))  # the onnxruntime baseline
        _print(bench("big", big, providers=fast))
        _print(bench("big", 2 * big, paced_hz=20.0, providers=fast))
        _print(bench("big", big, providers=fast, batch_rois=True))
        _print(bench("big", big, providers=fast, roi_every=2))
        _print(bench("big", big, rois=0, providers=fast))
    if only in (None, "two", "cli"):
        _print_cli(run_cli_two_cameras(max(frames, 60), fast))
    if only in (None, "big", "cli"):
        for windows in (2, 0):
            _print_cli(run_cli_big(max(big, 40), fast, windows))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

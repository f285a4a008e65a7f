"""``radarcal run`` performance: per-stage latency vs queued points, whole-loop FPS with a YOLOv5n-sized ONNX graph,
and memory over a 10 000-frame replay.

    PYTHONPATH=$PWD python -m benchmarks runtime            # everything (~3-4 min on 2 busy cores)
    PYTHONPATH=$PWD python -m benchmarks.runtime fusion     # one part: fusion | loop | memory

* fusion: the sample replay's rig (bundle, field model) with synthetic clouds (robots + terrain over the camera's
  view) at 50 k / 200 k / 1 M queued points (10 clouds in the 1 s queue, i.e. 5 k / 20 k / 100 k per 0.1 s cloud),
  12 robot boxes per frame, pinned to ONE core. Per camera frame (30 fps, clouds at 10 Hz) the fusion cost is the
  ingest of a third of a cloud (amortised) + the box depths + localisation + tracking. Peer in the same process: the
  dense per-cloud depth image of the NUAA report (``np.minimum.at`` into a full float image per cloud, box = slice).
* loop: the sample replay through the whole loop (JPEG decode, letterbox, onnxruntime on a *generated* graph of
  YOLOv5n's size — random weights, 2.3 GMAC / 1.7 M parameters, 1x25200x17 output, no real model is available
  here — decode/NMS, fusion, localisation, tracks, JSON lines) with 2 intra-op threads. The random graph finds no
  robots, so the boxes fused are the replay's detections (the detector still runs in full on every frame).
* memory: the sample replay cycled to 10 000 frames (clouds re-read from disk, JSON lines written); peak RSS
  (``ru_maxrss``) after 1 000 and after 10 000 frames.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "datasets" / "sample_replay"


def _rig():
    from radarcal.bundle import load_bundle
    from radarcal.runtime.loop import Pipeline, RunConfig

    b = load_bundle(SAMPLE / "calib.yaml")
    return b, Pipeline, RunConfig


def _synthetic_cloud(rng, n, T_lidar_field, robots_xy):
    """n LiDAR points: 85 % terrain in the camera's view (x 4..28 m), 15 % on robots (visible half-cylinders)."""
    from radarcal.geometry import transform_points

    n_rob = int(0.15 * n)
    k = len(robots_xy)
    idx = rng.integers(0, k, n_rob)
    ang = rng.uniform(0, 2 * np.pi, n_rob)
    rob = np.column_stack([robots_xy[idx, 0] + 0.27 * np.cos(ang), robots_xy[idx, 1] + 0.27 * np.sin(ang), rng.uniform(0.05, 0.5, n_rob)])
    ter = np.column_stack([rng.uniform(4, 28, n - n_rob), rng.uniform(0, 15, n - n_rob), rng.normal(0, 0.01, n - n_rob)])
    return transform_points(T_lidar_field, np.vstack([rob, ter])).astype(np.float32)


def _boxes(pipe, robots_xy):
    from radarcal.geometry import invert_T, transform_points

    T_cam_field = invert_T(pipe.T_field_cam)
    out = []
    for c in robots_xy:
        ang = np.linspace(0, 2 * np.pi, 16)
        pts = np.vstack([np.column_stack([c[0] + 0.27 * np.cos(ang), c[1] + 0.27 * np.sin(ang), np.full(16, z)]) for z in (0.0, 0.5)])
        uv, _ = pipe.camera.project(transform_points(T_cam_field, pts))
        out.append([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
    return np.array(out)


def _dense_peer(camera, T_cam_lidar, pts, boxes):
    """The dense per-cloud depth image (one full-resolution float image per cloud, nearest by np.minimum.at)."""
    from radarcal.geometry import transform_points

    w, h = camera.image_size
    p = transform_points(T_cam_lidar, pts)
    p = p[p[:, 2] > 0.3]
    uv, ok = camera.project(p)
    u, v = np.rint(uv[:, 0]), np.rint(uv[:, 1])
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    img = np.full(w * h, np.inf, np.float32)
    np.minimum.at(img, (v[ok] * w + u[ok]).astype(np.int64), p[ok, 2].astype(np.float32))
    img = img.reshape(h, w)
    return [img[int(b[1]) : int(b[3]) + 1, int(b[0]) : int(b[2]) + 1] for b in boxes]


def bench_fusion() -> list[dict]:
    from radarcal.geometry import invert_T
    from radarcal.runtime.detector import Detection

    try:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
        pinned = True
    except (AttributeError, OSError):
        pinned = False
    from radarcal.runtime.loop import limit_blas_threads

    b, Pipeline, RunConfig = _rig()
    rng = np.random.default_rng(0)
    rows = []
    blas = limit_blas_threads(1)
    blas.__enter__()
    for total in (50_000, 200_000, 1_000_000):
        per_cloud = total // 10
        cfg = RunConfig.from_bundle(b, cloud_queue_points=total, cloud_queue_age_s=10.0)
        pipe = Pipeline(b, "cam0", "lidar0", cfg)
        T_lidar_field = invert_T(pipe.T_field_cam @ b.T("cam0", "lidar0"))
        robots = np.column_stack([rng.uniform(12, 26, 12), rng.uniform(2, 13, 12)])
        boxes = _boxes(pipe, robots)
        inside = (boxes[:, 0] > 0) & (boxes[:, 2] < 1279) & (boxes[:, 1] > 0) & (boxes[:, 3] < 1023)
        robots, boxes = robots[inside], boxes[inside]
        dets = [Detection(bx, f"blue_{i}", 0.9) for i, bx in enumerate(boxes)]
        clouds = [_synthetic_cloud(rng, per_cloud, T_lidar_field, robots) for _ in range(13)]
        ingest, depth, loc, track = [], [], [], []
        t = 0.0
        for k, c in enumerate(clouds):  # fill the queue, then measure
            tic = time.perf_counter()
            pipe.add_cloud(t, c)
            ingest.append((time.perf_counter() - tic) * 1e3)
            for _ in range(3):
                for _rep in range(5 if k >= 10 else 1):  # more samples on a busy machine (same frame time)
                    res = pipe.process(t, "x", dets, {})
                    if k >= 10:
                        depth.append(res.timings_ms["depth"])
                        loc.append(res.timings_ms["localise"])
                        track.append(res.timings_ms["track"])
                t += 1 / 30
        ing = float(np.median(ingest[3:]))
        per_frame = ing / 3 + np.median(depth) + np.median(loc) + np.median(track)
        err = []
        for r in res.robots:
            i = int(r.label.split("_")[1])
            err.append(np.hypot(*(r.p_field[:2] - robots[i])))
        tic = time.perf_counter()
        for c in clouds[:3]:
            _dense_peer(pipe.camera, b.T("cam0", "lidar0"), c, boxes)
        dense = (time.perf_counter() - tic) / 3 * 1e3
        mem_sparse = sum(img.pix.nbytes + img.depth.nbytes for img in pipe.queue.images) / 1e6
        mem_dense = len(pipe.queue.images) * 1280 * 1024 * 4 / 1e6
        rows.append({"queued_points": pipe.queue.points, "clouds": len(pipe.queue), "boxes": len(dets), "ingest_ms_per_cloud": ing,
                     "depth_ms": float(np.median(depth)), "localise_ms": float(np.median(loc)), "track_ms": float(np.median(track)),
                     "fusion_loc_ms_per_frame": float(per_frame), "dense_peer_ms_per_cloud": dense, "sparse_MB": mem_sparse, "dense_peer_MB": mem_dense,
                     "median_err_m": float(np.median(err)), "one_core": pinned})  # fmt: skip
    blas.__exit__(None, None, None)
    try:
        os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
    except (AttributeError, OSError):
        pass
    return rows


def bench_loop(frames: int = 150) -> dict:
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector
    from radarcal.runtime.loop import run
    from radarcal.runtime.sources import CameraFrame, merge_by_time, open_replay, prefetch_frames
    from radarcal.runtime.synthetic_onnx import count_macs, make_yolov5n_like

    b, Pipeline, RunConfig = _rig()
    rep = open_replay(SAMPLE)
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "yolov5n_like.onnx"
        names = [f"{t}_{n}" for t in ("red", "blue") for n in (1, 2, 3, 4, 5, 7)]
        make_yolov5n_like(model, nc=len(names), names=names)
        det = OnnxDetector(model, threads=2)
        dfile = DetectionsFile.read(rep.detections)
        det_ms = []

        def detect(f):
            img = f.load()  # decoded ahead by the prefetch thread, as `radarcal run --detector` does
            tic = time.perf_counter()
            found = det(img)
            det_ms.append((time.perf_counter() - tic) * 1e3)
            assert isinstance(found, list)
            return dfile.lookup(f.t, f.name)

        pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))
        detect(next(rep.camera_frames(need_pixels=True)))  # warm-up
        det_ms.clear()
        cpu0 = time.process_time()
        period = (rep.timeline[-1][0] if rep.timeline else rep.frames[-1][0]) + 1 / 30

        def cycled_frames():  # the sample has an image every 10th frame: cycle them to get `frames` frames
            k = 0
            while True:
                for f in rep.camera_frames(need_pixels=True):
                    yield CameraFrame(f.t + k * period, f.name, f.load, f.index)
                k += 1

        def cycled_clouds():
            k = 0
            while True:
                for c in rep.cloud_frames():
                    yield dataclasses.replace(c, t=c.t + k * period)
                k += 1

        def detect_cycled(f):
            f2 = CameraFrame(f.t % period, f.name, f.load, f.index)
            return detect(f2)

        s = run(pipe, merge_by_time(prefetch_frames(cycled_frames()), cycled_clouds()), detect_cycled, out_path=Path(tmp) / "o.jsonl", status=False, max_frames=frames)
        cpu = time.process_time() - cpu0
        # peer in the same process: OpenCV's DNN module on the same graph, if it can load it
        cv_ms = None
        try:
            import cv2

            net = cv2.dnn.readNetFromONNX(str(model))
            cv2.setNumThreads(2)
            x = np.zeros((1, 3, 640, 640), np.float32)
            net.setInput(x)
            net.forward()
            tic = time.perf_counter()
            for _ in range(10):
                net.setInput(x)
                net.forward()
            cv_ms = (time.perf_counter() - tic) / 10 * 1e3
        except Exception as e:  # noqa: BLE001 - report, do not fail the benchmark
            cv_ms = f"cv2.dnn failed: {e.__class__.__name__}"
    macs, params = count_macs(640, len(names))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return {"frames": s["frames"], "fps": s["fps"], "cpu_ms_per_frame": cpu / s["frames"] * 1e3, "fps_cpu_bound_1core": s["frames"] / cpu, "load": load,
            "detector_ms_median": float(np.median(det_ms)), "gmac": macs / 1e9, "params_M": params / 1e6,
            "cv2_dnn_ms": cv_ms, "stages": {k: v["median"] for k, v in s["latency_ms"].items()}}  # fmt: skip


def bench_memory(total: int = 10_000) -> dict:
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.loop import run
    from radarcal.io import Cloud
    from radarcal.runtime.sources import CameraFrame, merge_by_time, open_replay

    b, Pipeline, RunConfig = _rig()
    rep = open_replay(SAMPLE)
    dfile = DetectionsFile.read(rep.detections)
    timeline = rep.timeline or [(t, p.name) for t, p in rep.frames]
    period = timeline[-1][0] + 1 / 30
    n_src = len(timeline)

    def frames():
        for i in range(total):
            k, t0 = i % n_src, (i // n_src) * period
            t, name = timeline[k]
            yield CameraFrame(t0 + t, name, lambda: None, i)

    def clouds():
        from radarcal.io import read_cloud

        cycle = 0
        while True:
            for t, p in rep.clouds:
                yield Cloud(read_cloud(p).points, t=cycle * period + t)
            cycle += 1

    rss, cur = {}, {}

    def current_rss_mb() -> float:
        try:
            for line in open("/proc/self/status"):
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
        except OSError:
            pass
        return float("nan")

    def on_frame(n, res):
        if n + 1 in (100, 1000, 2000, 5000, total):
            rss[n + 1] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
            cur[n + 1] = current_rss_mb()

    pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))
    with tempfile.TemporaryDirectory() as tmp:
        s = run(pipe, merge_by_time(frames(), clouds()), lambda f: dfile.lookup(f.t - (f.index // n_src) * period, f.name), out_path=Path(tmp) / "o.jsonl",
                minimap_path=Path(tmp) / "m.png", status=False, on_frame=on_frame)  # fmt: skip
    return {"frames": s["frames"], "fps": s["fps"], "peak_rss_MB": rss, "rss_MB": cur}


def main(argv: list[str]) -> int:
    parts = argv or ["fusion", "loop", "memory"]
    if not (SAMPLE / "meta.json").is_file():
        print(f"{SAMPLE} missing: run python datasets/make_sample.py")
        return 1
    if "fusion" in parts:
        print("fusion + localisation per camera frame, ONE core (clouds 10 Hz, frames 30 Hz -> 1/3 cloud ingest per frame)")
        print(f"{'queued pts':>10} {'clouds':>6} {'boxes':>5} {'ingest/cloud':>12} {'depth':>7} {'localise':>8} {'track':>7} {'=> per frame':>12} {'dense peer/cloud':>16} {'sparse MB':>9} {'dense MB':>8} {'err m':>6}")
        for r in bench_fusion():
            print(f"{r['queued_points']:>10} {r['clouds']:>6} {r['boxes']:>5} {r['ingest_ms_per_cloud']:>10.2f}ms {r['depth_ms']:>5.2f}ms {r['localise_ms']:>6.2f}ms "
                  f"{r['track_ms']:>5.2f}ms {r['fusion_loc_ms_per_frame']:>10.2f}ms {r['dense_peer_ms_per_cloud']:>14.2f}ms {r['sparse_MB']:>9.1f} {r['dense_peer_MB']:>8.1f} {r['median_err_m']:>6.3f}")
        sys.stdout.flush()
    if "loop" in parts:
        r = bench_loop()
        print(f"\nwhole loop, generated YOLOv5n-sized graph ({r['gmac']:.2f} GMAC, {r['params_M']:.2f} M params, random weights) at 640, 2 threads:")
        cv = r["cv2_dnn_ms"] if isinstance(r["cv2_dnn_ms"], str) else f"{r['cv2_dnn_ms']:.1f} ms (inference only)"
        print(f"  {r['frames']} frames, {r['fps']:.1f} FPS; detector (letterbox+onnxruntime+decode) median {r['detector_ms_median']:.1f} ms; cv2.dnn on the same graph: {cv}")
        print("  stage medians ms: " + ", ".join(f"{k} {v:.2f}" for k, v in r["stages"].items()))
        print(f"  CPU time {r['cpu_ms_per_frame']:.1f} ms per frame (all threads) -> >= {r['fps_cpu_bound_1core']:.1f} FPS with the CPU time of ONE free core "
              f"(1-min load average during the run: {r['load']:.1f} on {os.cpu_count()} cores)")
        sys.stdout.flush()
    if "memory" in parts:
        r = bench_memory()
        print(f"\n10 000-frame replay (sample cycled, clouds re-read, JSON lines + minimap): {r['frames']} frames at {r['fps']:.0f} FPS")
        print("  peak RSS MB after N frames: " + ", ".join(f"{k}: {v:.1f}" for k, v in sorted(r["peak_rss_MB"].items())))
        print("  current RSS MB after N frames: " + ", ".join(f"{k}: {v:.1f}" for k, v in sorted(r["rss_MB"].items())))
        print("  (peak RSS is per process: run `python -m benchmarks.runtime memory` alone for the loop's own figure)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

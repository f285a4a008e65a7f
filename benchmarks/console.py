"""The live console's cost to the match loop: loop FPS over the sample replay (unpaced, as fast as it goes) with the
console closed vs open with a real headless Chromium page connected (minimap stream at up to 30 Hz, camera JPEG
polled every 300 ms), alternating runs in one process, median of the ratios.

    PYTHONPATH=$PWD python -m benchmarks console [runs]

The "python" client is a separate process that reads the event stream and the camera JPEG at the page's rates
(isolates the console's in-process cost from Chromium's own CPU use; the only client without Chromium + selenium).
Paced runs replay at the camera's 30 FPS, as a live camera does: the FPS then says whether the loop keeps up, and
"busy" is the loop's own time per frame (sum of its stage timings).
"""

from __future__ import annotations

import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "datasets" / "sample_replay"


def _one_run(console_client: str | None, speed: float = 0.0) -> tuple[float, dict]:
    from radarcal.bundle import load_bundle
    from radarcal.runtime.console.live import LiveConsole, chain_callbacks, paced
    from radarcal.runtime.console.server import WebServer
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.loop import Pipeline, RunConfig, run
    from radarcal.runtime.sources import merge_by_time, open_replay

    rep = open_replay(SAMPLE)
    b = load_bundle(rep.bundle)
    pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b))
    dets = DetectionsFile.read(rep.detections)
    pairs = merge_by_time(rep.camera_frames(), rep.cloud_frames())
    pairs = paced(pairs, speed) if speed > 0 else pairs
    def detect(f):
        return dets.lookup(f.t, f.name)
    busy: list[float] = []  # the loop's own time per frame (sum of its stage timings)
    on_frame, srv, stop, extra = (lambda n, res: busy.append(sum(res.timings_ms.values()))), None, None, {}
    if console_client is not None:
        srv = WebServer("127.0.0.1", 0, log=lambda s: None)
        con = LiveConsole(srv, pipe.field_model, pipe.camera, b.T("cam0", "lidar0"))
        srv.start()
        pairs, detect, on_frame = con.observe_pairs(pairs), con.observe_detect(detect), chain_callbacks(on_frame, con.on_frame)
        stop = threading.Event()
        if console_client == "chromium":
            drv = _chromium()
            drv.get(srv.url)
            extra["driver"] = drv
        else:  # a separate process, like a browser (its reads must not take this process's GIL)
            import subprocess

            extra["proc"] = subprocess.Popen([sys.executable, "-c", ("import sys, threading; from benchmarks.console import _python_client; "
                                              "_python_client(sys.argv[1], threading.Event())"), srv.url], cwd=ROOT)  # fmt: skip
        time.sleep(1.0)  # page loaded and connected before the loop starts
    s = run(pipe, pairs, detect, status=False, on_frame=on_frame)
    if srv is not None:
        if "driver" in extra:
            extra["updates"] = extra["driver"].execute_script("return window.__console.updates;")
            extra["driver"].quit()
        if "proc" in extra:
            extra.pop("proc").kill()
        stop.set()
        srv.close()
    extra["busy_ms"] = np.array(busy)
    return s["fps"], extra


def _python_client(url: str, stop: threading.Event) -> None:
    def events():
        with urllib.request.urlopen(url + "api/events", timeout=10) as r:
            while not stop.is_set() and r.readline():
                pass

    threading.Thread(target=events, daemon=True).start()
    while not stop.is_set():
        try:
            urllib.request.urlopen(url + "api/camera.jpg", timeout=5).read()
        except OSError:
            pass
        time.sleep(0.3)


def _chromium():
    import shutil

    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    import tempfile

    for a in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--disable-sync",
              "--no-first-run", "--disable-dev-shm-usage", f"--user-data-dir={tempfile.mkdtemp(prefix='radarcal-bench-')}", "--window-size=1500,1100"):  # fmt: skip
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(shutil.which("chromedriver") or "/usr/bin/chromedriver"), options=opts)


def _hot_path_cost() -> None:
    """What the console adds to the loop's own thread: ``on_frame`` plus the two iterator wrappers, per frame, with a
    stream reader connected (timed directly; independent of the machine's load from other processes)."""
    from radarcal.runtime.console.live import LiveConsole
    from radarcal.runtime.console.server import WebServer
    from radarcal.io.clouds import Cloud
    from radarcal.runtime.sources import CameraFrame

    srv = WebServer("127.0.0.1", 0, log=lambda s: None)
    con = LiveConsole(srv)
    srv.start()
    stop = threading.Event()
    threading.Thread(target=lambda: [None for _ in urllib.request.urlopen(srv.url + "api/events", timeout=10)], daemon=True).start()
    time.sleep(0.3)

    class Res:
        t, frame, robots = 0.0, "x", []

        def to_dict(self):
            return {"t": 0.0, "frame": "x", "robots": [{"label": f"red_{i}", "x": 1.0, "y": 2.0} for i in range(12)]}

    frames = ((CameraFrame(i / 30, f"{i}", lambda: None, i), [Cloud(np.zeros((10, 3), np.float32), t=i / 30)]) for i in range(20000))
    det = con.observe_detect(lambda f: [])
    cost = []
    it = con.observe_pairs(frames)
    r = Res()
    for i in range(20000):
        tic = time.perf_counter()
        f, _ = next(it)
        det(f)
        con.on_frame(i, r)
        cost.append(time.perf_counter() - tic)
        if i % 50 == 0:
            time.sleep(0.001)  # let the stream thread run, as between real frames
    stop.set()
    srv.close()
    c = np.array(cost) * 1e6
    print(f"console on the loop's thread per frame (wrappers + on_frame, stream connected): median {np.median(c):.1f} us, p99 {np.percentile(c, 99):.1f} us, "
          f"max {c.max():.0f} us")  # fmt: skip


def main(argv: list[str]) -> int:
    runs = int(argv[0]) if argv else 5
    client = "python"
    try:
        import shutil

        import selenium  # noqa: F401

        if shutil.which("chromium") and shutil.which("chromedriver"):
            client = "chromium"
    except ImportError:
        pass
    _one_run(None)  # warm-up (imports, page cache)
    _hot_path_cost()
    clients = [client] if client == "python" else [client, "python"]
    for speed, what in ((0.0, "unpaced (as fast as it goes): loop FPS"), (1.0, "paced at the camera's 30 FPS: the loop's own time per frame")):
        print(f"\nsample replay, 300 frames, {what}; {runs} alternating runs per client")
        print(f"{'console':<18} {'FPS med':>8} {'min':>7} {'max':>7} {'busy ms med':>12} {'p95':>7} {'page updates':>13}")
        for cl in clients:
            closed, opened, bc, bo, ups = [], [], [], [], []
            for i in range(runs):
                for kind in ((None, cl) if i % 2 == 0 else (cl, None)):
                    fps, extra = _one_run(kind, speed)
                    (closed if kind is None else opened).append(fps)
                    (bc if kind is None else bo).append(extra["busy_ms"])
                    if "updates" in extra:
                        ups.append(extra["updates"])
            for name, f, bz in (("closed", closed, bc), (f"open ({cl})", opened, bo)):
                f, bz = np.array(f), np.concatenate(bz)
                u = f"{int(np.median(ups))}" if ups and name != "closed" else ""
                print(f"{name:<18} {np.median(f):8.1f} {f.min():7.1f} {f.max():7.1f} {np.median(bz):12.2f} {np.percentile(bz, 95):7.2f} {u:>13}")
            r = np.array(opened) / np.array(closed)
            print(f"  open/closed FPS: median of pairs {np.median(r):.3f} ({', '.join(f'{v:.2f}' for v in r)}); busy-time ratio (median) "
                  f"{np.median(np.concatenate(bo)) / np.median(np.concatenate(bc)):.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

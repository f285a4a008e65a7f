"""Livox input benchmarks: HAP-rate (452 k points/s) receive + decode CPU, and recording 100 k points/s + 30 FPS
1280x1024 (CPU %, MB/s, drops). The simulator runs in its own process (``radarcal synth livox-sim``) on loopback.

    python -m benchmarks livox            # 20 s HAP, 60 s recording
    python -m benchmarks.livox --record-s 600
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _sim(model: str, ip: str, duration: float, port: int | None = None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "radarcal", "synth", "livox-sim", "--model", model, "--ip", ip, "--duration", str(duration)]
    if port:
        cmd += ["--discovery-port", str(port)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def decode_only() -> dict:
    """PacketDecoder on one second of pre-encoded HAP packets (no sockets)."""
    from radarcal.io.livox import PacketDecoder, sdk2

    n = 4708
    rng = np.random.default_rng(0)
    pk = sdk2.encode_packets(rng.uniform(-50, 50, (n * 96, 3)), rng.integers(0, 255, n * 96), 10**9)
    raw = [p.tobytes() for p in pk]
    dec = PacketDecoder(2)
    t0 = time.process_time()
    for i, b in enumerate(raw):
        dec.feed(b, i / n)
        if dec.pending() >= 256:
            dec.flush()
    dec.finish()
    return {"cpu_s_per_s_of_data": time.process_time() - t0, "points": dec.health.points}


def hap_live(seconds: float) -> dict:
    from radarcal.io.livox import LivoxSource

    sim = _sim("hap", "127.0.8.1", seconds + 6)
    src = LivoxSource("127.0.8.1", host="127.0.0.1", sensor="hap").start()
    try:
        end = time.monotonic() + 30
        while src.health.state != "streaming" and time.monotonic() < end:
            time.sleep(0.05)
        time.sleep(1.0)
        c0, p0, w0 = src.health.cpu_s, src.health.points, time.monotonic()
        while time.monotonic() - w0 < seconds:
            src.poll()
            time.sleep(0.05)
        c1, p1, w1 = src.health.cpu_s, src.health.points, time.monotonic()
        h = src.snapshot()
    finally:
        src.close()
        sim.wait()
    return {"points_per_s": (p1 - p0) / (w1 - w0), "cpu_core_fraction": (c1 - c0) / (w1 - w0), "drops": h["drops"], "bad": h["bad_packets"]}


def recording(seconds: float) -> dict:
    from radarcal.io import clock
    from radarcal.io.livox import LivoxSource
    from radarcal.io.recording import Recorder

    sim = _sim("mid70", "127.0.8.2", seconds + 8, port=45321)
    out = Path(tempfile.mkdtemp()) / "rec"
    rec = Recorder(out, [{"name": "lidar0", "kind": "lidar"}, {"name": "cam0", "kind": "camera"}])
    src = LivoxSource("127.0.8.2", host="127.0.0.1", sensor="lidar0", discovery_port=45321, packet_tap=rec.lidar).start()
    rng = np.random.default_rng(0)
    base = cv2_img = None
    import cv2

    base = cv2.GaussianBlur(rng.integers(0, 255, (1024, 1280, 3), dtype=np.uint8), (0, 0), 3)  # a textured 1280x1024 frame
    try:
        end = time.monotonic() + 30
        while src.health.state != "streaming" and time.monotonic() < end:
            time.sleep(0.05)
        w0, c0 = time.monotonic(), time.process_time()
        k = 0
        while time.monotonic() - w0 < seconds:
            due = w0 + k / 30.0
            now = time.monotonic()
            if now < due:
                time.sleep(due - now)
            cv2_img = np.roll(base, k * 3, axis=1)  # the picture changes every frame
            rec.camera("cam0", clock.now(), f"{k:06d}", cv2_img)
            src.poll()
            k += 1
        h = src.snapshot()
    finally:
        src.close()
        man = rec.close()
        c1, w1 = time.process_time(), time.monotonic()
        sim.wait()
    mb = sum(c["bytes"] for c in man["streams"].values()) / 1e6
    return {"seconds": w1 - w0, "frames": k, "dropped_frames": man["dropped_camera_frames"], "lidar_drops": h["drops"], "lidar_points": h["points"],
            "cpu_percent_of_one_core": 100 * (c1 - c0) / (w1 - w0), "MB_per_s": mb / (w1 - w0)}  # fmt: skip


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hap-s", type=float, default=20.0)
    ap.add_argument("--record-s", type=float, default=60.0)
    a = ap.parse_args(argv)
    d = decode_only()
    print(f"decode only, 1 s of HAP packets (452 k points): {d['cpu_s_per_s_of_data'] * 1000:.0f} ms CPU  ({100 * d['cpu_s_per_s_of_data']:.1f} % of one core)")
    h = hap_live(a.hap_s)
    print(f"HAP live over loopback, {a.hap_s:.0f} s: {h['points_per_s'] / 1000:.0f} k points/s received, I/O thread {100 * h['cpu_core_fraction']:.1f} % of one core, "
          f"drops {h['drops']}")  # fmt: skip
    r = recording(a.record_s)
    print(f"recording {r['seconds']:.0f} s of Mid-70 (100 k pts/s) + 30 FPS 1280x1024: process CPU {r['cpu_percent_of_one_core']:.0f} % of one core, "
          f"{r['MB_per_s']:.2f} MB/s, camera frames {r['frames']} (dropped {r['dropped_frames']}), LiDAR drops {r['lidar_drops']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

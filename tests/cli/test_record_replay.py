"""`radarcal record` (simulated LiDAR, a video, a pseudo-terminal referee) -> `radarcal run --replay` twice:
byte-identical tracks; the referee input replayed at its times; the output on a pseudo-terminal."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest

from radarcal.cli.main import main
from radarcal.runtime import referee as rp

SAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "sample_replay"


@pytest.fixture(scope="module")
def sample():
    if not (SAMPLE / "meta.json").is_file():
        pytest.skip("datasets/sample_replay missing")
    return SAMPLE


def _video(path: Path, n: int) -> None:
    import cv2

    imgs = sorted((SAMPLE / "images").glob("*.jpg"))
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 512))
    for i in range(n):
        img = cv2.resize(cv2.imread(str(imgs[(i // 10) % len(imgs)])), (640, 512))
        w.write(img)
    w.release()


@pytest.mark.slow
def test_record_then_two_replays_are_byte_identical(sample, tmp_path, capsys):
    from radarcal.synth.livox_sim import LivoxSimulator

    n_frames = 90  # 3 s at 30 FPS
    _video(tmp_path / "cam.avi", n_frames)
    # detections named like the video frames (000000 ...)
    det = [json.loads(x) for x in (sample / "detections.jsonl").read_text().splitlines()][:n_frames]
    (tmp_path / "det.jsonl").write_text("".join(json.dumps({**d, "frame": d["frame"].split(".")[0]}) + "\n" for d in det))
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    stop = threading.Event()

    def referee():  # robot status 0x0201 of blue radar (109) ten times a second
        k = 0
        while not stop.is_set():
            os.write(master, rp.pack_frame(rp.CMD_ROBOT_STATUS, bytes([109]) + bytes(12), k & 0xFF))
            k += 1
            time.sleep(0.1)

    th = threading.Thread(target=referee, daemon=True)
    th.start()
    sim = LivoxSimulator("mid70", ip="127.0.9.7", host="127.0.0.1", discovery_port=45123, scene=sample).start()
    rec = tmp_path / "rec"
    try:
        code = main(["record", str(rec), "--clouds", "lidar0=livox://127.0.9.7?host=127.0.0.1&discovery_port=45123", "--video", str(tmp_path / "cam.avi"),
                     "--serial", os.ttyname(slave), "--bundle", str(sample / "calib.yaml"), "--json"])  # fmt: skip
    finally:
        stop.set()
        sim.close()
        th.join()
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["streams"]["camera-cam0"]["records"] == n_frames and s["dropped_camera_frames"] == 0
    h = s["lidars"]["lidar0"]
    assert h["sdk"] == 1 and h["drops"] == 0 and h["packets"] > 2000 and s["streams"]["serial"]["records"] >= 10
    assert s["streams"]["lidar-lidar0"]["records"] >= h["packets"]
    man = json.loads((rec / "manifest.json").read_text())
    assert man["bundle"]["sha256"] and {x["kind"] for x in man["sensors"]} >= {"lidar", "camera", "serial"}

    outs = []
    for k, serial in enumerate(["dry-run", "pty"]):
        o = tmp_path / f"tracks{k}.jsonl"
        code = main(["run", "--replay", str(rec), "--detections", str(tmp_path / "det.jsonl"), "--out", str(o), "--serial", serial, "--json"])
        r = json.loads(capsys.readouterr().out)
        assert code == 0 and r["frames"] == n_frames and r["clouds"] >= 25 and r["team"] == "blue"
        assert r["serial"]["received"] >= 10 and r["serial"]["sent"] > 0
        outs.append(o.read_bytes())
    assert outs[0] == outs[1]
    lines = [json.loads(x) for x in outs[0].decode().splitlines()]
    assert len(lines) == n_frames and "latency_ms" not in lines[0]
    assert sum(r["source"] == "depth" for ln in lines for r in ln["robots"]) > 50  # the replayed LiDAR gave depth

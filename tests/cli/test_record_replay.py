"""`radarcal record` (simulated LiDAR, a video, a pseudo-terminal referee) -> `radarcal run --replay` twice:
byte-identical tracks; the referee input replayed at its times; the output on a pseudo-terminal."""

from __future__ import annotations

import json
from collections import Counter
import os
import threading
import time
from pathlib import Path

import numpy as np
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
    sources = Counter(r["source"] for ln in lines for r in ln["robots"])
    print("sources", dict(sources))
    # the replayed LiDAR located robots: its clusters (LiDAR-first, the default) or the depth in their boxes
    assert sources["lidar"] + sources["depth"] > 0.6 * sum(sources.values()), sources


def _positions(path: Path) -> dict[str, dict[str, tuple]]:
    out = {}
    for ln in path.read_text().splitlines():
        d = json.loads(ln)
        out[d["frame"]] = {r["label"]: (r["x"], r["y"], r["source"]) for r in d["robots"]}
    return out


@pytest.mark.slow
def test_live_run_with_record_matches_its_replays(sample, tmp_path, capsys):
    """A live run (simulated Mid-70 streaming the sample scene, a video at its frame rate, a pseudo-terminal referee)
    recording itself; its two replays are byte-identical and agree with the live tracks within timing jitter."""
    from radarcal.synth.livox_sim import LivoxSimulator

    n_frames = 150  # 5 s
    _video(tmp_path / "cam.avi", n_frames)
    det = [json.loads(x) for x in (sample / "detections.jsonl").read_text().splitlines()][:n_frames]
    (tmp_path / "det.jsonl").write_text("".join(json.dumps({**d, "frame": d["frame"].split(".")[0]}) + "\n" for d in det))
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    stop = threading.Event()

    def referee():
        k = 0
        while not stop.is_set():
            os.write(master, rp.pack_frame(rp.CMD_ROBOT_STATUS, bytes([109]) + bytes(12), k & 0xFF))
            k += 1
            time.sleep(0.1)
            try:  # drain what radarcal sends (the minimap frames)
                os.read(master, 4096)
            except BlockingIOError:
                pass

    os.set_blocking(master, False)
    th = threading.Thread(target=referee, daemon=True)
    th.start()
    sim = LivoxSimulator("mid70", ip="127.0.9.8", host="127.0.0.1", discovery_port=45124, scene=sample).start()
    rec, live = tmp_path / "rec", tmp_path / "live.jsonl"
    try:
        time.sleep(0.5)
        code = main(["run", "--bundle", str(sample / "calib.yaml"), "--video", str(tmp_path / "cam.avi"), "--realtime-video",
                     "--clouds", "lidar0=livox://127.0.9.8?host=127.0.0.1&discovery_port=45124", "--detections", str(tmp_path / "det.jsonl"),
                     "--serial", os.ttyname(slave), "--record", str(rec), "--out", str(live), "--json"])  # fmt: skip
    finally:
        stop.set()
        sim.close()
        th.join()
    cap = capsys.readouterr()
    assert code == 0, cap.err[-2000:]
    s = json.loads(cap.out)
    assert s["frames"] == n_frames and s["health"]["lidar0"]["drops"] == 0 and s["recording"]["dropped_camera_frames"] == 0
    outs = []
    for k in range(2):
        o = tmp_path / f"r{k}.jsonl"
        assert main(["run", "--replay", str(rec), "--detections", str(tmp_path / "det.jsonl"), "--out", str(o), "--json"]) == 0
        capsys.readouterr()
        outs.append(o)
    assert outs[0].read_bytes() == outs[1].read_bytes()
    a, b = _positions(live), _positions(outs[0])
    assert list(a) == list(b)
    same = sum(a[f] == b[f] for f in a)
    diffs = [np.hypot(a[f][k][0] - b[f][k][0], a[f][k][1] - b[f][k][1]) for f in a for k in a[f] if k in b[f]]
    labels_same = sum(set(a[f]) == set(b[f]) for f in a)
    print(f"live vs replay: {same}/{len(a)} frames identical, labels equal in {labels_same}, position diff median {np.median(diffs):.3f} m, "
          f"p95 {np.percentile(diffs, 95):.3f} m, max {np.max(diffs):.3f} m")  # fmt: skip
    assert labels_same >= 0.95 * len(a) and np.median(diffs) < 0.02 and np.percentile(diffs, 95) < 0.3


def test_bad_inputs_one_line_errors_and_nothing_written(tmp_path, capsys):
    assert main(["record", str(tmp_path / "r")]) == 2 and "nothing to record" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    assert main(["record", str(tmp_path / "r"), "--video", str(tmp_path / "missing.avi")]) == 2
    assert "video file not found" in capsys.readouterr().err and not (tmp_path / "r").exists()
    assert main(["record", str(tmp_path / "r"), "--clouds", "livox://127.0.0.1:56001"]) == 2
    assert "starts the LiDAR itself" in capsys.readouterr().err
    assert main(["record", str(tmp_path / "r"), "--clouds", "livox://not-an-ip"]) == 2
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("x")
    assert main(["record", str(full), "--serial", "/dev/nonexistent-tty"]) == 2
    assert "not empty" in capsys.readouterr().err and [p.name for p in full.iterdir()] == ["keep.txt"]
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "manifest.json").write_text('{"format": "radarcal-recording", "version": 99}')
    assert main(["run", "--replay", str(rec), "--bundle", str(SAMPLE / "calib.yaml"), "--detections", str(SAMPLE / "detections.jsonl")]) == 2
    assert "newer than this radarcal reads" in capsys.readouterr().err

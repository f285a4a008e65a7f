"""`radarcal run` and `radarcal hero-offset` through the real CLI entry point."""

from __future__ import annotations

import json
import os
import select
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from radarcal.bundle import load_bundle
from radarcal.cli.main import main
from radarcal.runtime import referee as rp

SAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "sample_replay"


@pytest.fixture(scope="module")
def sample():
    if not (SAMPLE / "meta.json").is_file():
        pytest.skip("datasets/sample_replay missing (python datasets/make_sample.py)")
    return SAMPLE


def test_run_replay_json_outputs(sample, tmp_path, capsys):
    out, mm = tmp_path / "tracks.jsonl", tmp_path / "map.png"
    code = main(["run", "--replay", str(sample), "--out", str(out), "--minimap", str(mm), "--json"])
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["frames"] == 300 and s["clouds"] == 100 and s["lidar"] == "lidar0"
    # default --localise auto: no robot before the first cloud / three consistent boxes (a few start-up frames)
    acc = s["accuracy"]
    assert s["localise"] == "auto" and acc["missing"] < 0.02 * acc["visible"] and acc["median_m"] < 0.3 and acc["p95_m"] < 0.8, acc
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == 300 and {"t", "frame", "robots", "sentry", "hero_range_m", "latency_ms"} <= set(lines[0])
    rob = lines[-1]["robots"][0]
    assert {"label", "x", "y", "z", "source", "sigma", "depth"} <= set(rob)
    import cv2

    img = cv2.imread(str(mm))
    assert img is not None and img.shape[1] > img.shape[0] > 300


def test_run_separate_sources_and_status_line(sample, tmp_path, capsys):
    code = main(["run", "--bundle", str(sample / "calib.yaml"), "--video", str(sample / "images"), "--clouds", str(sample / "clouds"),
                 "--detections", str(sample / "detections.jsonl"), "--out", str(tmp_path / "o.jsonl"), "--max-frames", "20"])  # fmt: skip
    cap = capsys.readouterr()
    # the image folder holds every 10th frame (3 fps): frames pair with their detections by name, clouds by time
    assert code == 0 and "20 frames" in cap.out and "FPS" in cap.err
    lines = [json.loads(x) for x in (tmp_path / "o.jsonl").read_text().splitlines()]
    assert len(lines) == 20 and lines[1]["frame"] == "000010.jpg" and any(r["source"] in ("depth", "lidar") for ln in lines for r in ln["robots"])


@pytest.mark.parametrize("workers", ["1", "2"])
def test_run_with_generated_onnx_detector(sample, tmp_path, capsys, workers):
    from radarcal.runtime.synthetic_onnx import make_fixed_boxes_model

    # a model that "detects" blue_1 where truth.jsonl puts it in frame 0 (1280x1024 -> 640 letterbox: x0.5, +64 y)
    t0 = json.loads((sample / "truth.jsonl").read_text().splitlines()[0])
    x1, y1, x2, y2 = next(r["xyxy"] for r in t0["robots"] if r["label"] == "blue_1")
    row = np.zeros(7, np.float32)
    row[:5] = [(x1 + x2) / 4, (y1 + y2) / 4 + 64, (x2 - x1) / 2, (y2 - y1) / 2, 0.9]
    row[5] = 1.0
    model = tmp_path / "m.onnx"
    make_fixed_boxes_model(model, np.stack([row, np.zeros(7, np.float32)]), 640, ["blue_1", "red_3"])
    # the box path locates from the first box (LiDAR-first, the default, waits for three consistent frames)
    code = main(["run", "--replay", str(sample), "--detector", str(model), "--max-frames", "3", "--out", str(tmp_path / "o.jsonl"), "--json", "--localise", "box",
                 "--detect-workers", workers, "--threads", "1"])  # fmt: skip
    assert code == 0
    first = json.loads((tmp_path / "o.jsonl").read_text().splitlines()[0])
    assert [r["label"] for r in first["robots"]] == ["blue_1"]
    truth = next(r for r in t0["robots"] if r["label"] == "blue_1")["p_field"]
    assert np.hypot(first["robots"][0]["x"] - truth[0], first["robots"][0]["y"] - truth[1]) < 0.5


def test_hero_offset_stored_and_used(sample, tmp_path, capsys):
    bundle = tmp_path / "calib.yaml"
    shutil.copy(sample / "calib.yaml", bundle)
    assert main(["hero-offset", "--bundle", str(bundle), "--measured", "10.3", "--actual", "9.8", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["hero_range_offset_m"] == pytest.approx(-0.5)
    assert load_bundle(bundle).runtime["hero_range_offset_m"] == pytest.approx(-0.5)
    assert list(tmp_path.glob("calib.yaml.*.bak"))  # the previous bundle kept (atomic save with backup)
    ranges = {}
    for name, b in (("plain", sample / "calib.yaml"), ("offset", bundle)):
        out = tmp_path / f"{name}.jsonl"
        assert main(["run", "--replay", str(sample), "--bundle", str(b), "--team", "blue", "--max-frames", "10", "--out", str(out), "-q", "--localise", "box"]) == 0
        ranges[name] = [json.loads(x)["hero_range_m"] for x in out.read_text().splitlines()]
    np.testing.assert_allclose(np.array(ranges["offset"]) - np.array(ranges["plain"]), -0.5, atol=1e-6)
    assert main(["hero-offset", "--bundle", str(bundle), "--measured", "-3", "--actual", "9.8"]) == 2


def test_run_talks_to_the_referee_over_a_pty(sample, tmp_path, capsys):
    master, slave = os.openpty()
    os.set_blocking(master, False)
    os.write(master, b"")
    try:
        # the referee says we are blue (0x0201 robot id 109) before the run starts
        code = None
        import threading

        parser = rp.FrameParser()
        got = []
        stop = threading.Event()

        def reader():
            told = False
            while not stop.is_set():
                r, _, _ = select.select([master], [], [], 0.02)
                if r:
                    try:
                        got.extend(parser.feed(os.read(master, 4096)))
                    except (BlockingIOError, OSError):
                        pass
                if got and not told:  # the link is up: the referee tells the radar it is blue (0x0201, id 109)
                    os.write(master, rp.pack_frame(rp.CMD_ROBOT_STATUS, bytes([109, 1]) + bytes(11)))
                    told = True

        th = threading.Thread(target=reader, daemon=True)
        th.start()
        code = main(["run", "--replay", str(sample), "--serial", os.ttyname(slave), "--season", "2026", "--json", "--max-frames", "150"])
        time.sleep(0.1)
        stop.set()
        th.join(1)
    finally:
        os.close(master)
        os.close(slave)
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["serial"]["sent"] > 0
    maps = [f for f in got if f.cmd_id == rp.CMD_MAP]
    assert maps and all(len(f.data) == 48 for f in maps)  # 2026 layout
    assert parser.stats.bad_crc16 == parser.stats.bad_crc8 == 0
    # <= 5 Hz for 0x0305 in 2026: 150 frames at full speed take well under the time that would allow more
    assert len(maps) <= 5 * s["wall_s"] + 2
    assert s["serial"]["team"] == "blue"
    import struct

    vals = [struct.unpack("<24H", f.data) for f in maps]
    as_blue = [v for v in vals if v[12:14] != (0, 0)]  # blue_1 (our hero now) in the ally hero slot
    assert as_blue and vals[-1] in as_blue  # the switch happened and stuck
    assert all(v[0:2] == (0, 0) and v[10:12] == (0, 0) for v in as_blue)  # no blue robot in the enemy slots any more


@pytest.mark.parametrize("argv,msg", [
    (["run", "--replay", "/nonexistent/replay"], "replay folder not found"),
    (["run", "--replay", str(SAMPLE), "--video", "x.mp4"], "exactly one of"),
    (["run", "--replay", str(SAMPLE), "--team", "green"], "red or blue"),
    (["run", "--replay", str(SAMPLE), "--detector", "/nonexistent.onnx"], "ONNX model not found"),
    (["run", "--replay", str(SAMPLE), "--sentry-xy", "1"], "X,Y"),
])  # fmt: skip
def test_run_bad_input_is_one_line_exit_2(sample, argv, msg, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_run_bad_bundle_and_detections(sample, tmp_path, capsys):
    bad = tmp_path / "d.jsonl"
    bad.write_text("{not json\n")
    assert main(["run", "--replay", str(sample), "--detections", str(bad)]) == 2
    assert "d.jsonl: line 1" in capsys.readouterr().err
    b = tmp_path / "b.yaml"
    b.write_text("schema_version: 1\ncameras: {}\n")
    assert main(["run", "--replay", str(sample), "--bundle", str(b)]) == 2
    assert "no camera 'cam0' in the bundle" in capsys.readouterr().err
    b.write_text((sample / "calib.yaml").read_text().replace("T_field_cam0:", "T_fieldX_cam0:").replace("target: field", "target: fieldX"))
    assert main(["run", "--replay", str(sample), "--bundle", str(b)]) == 2
    assert "no field pose for 'cam0'" in capsys.readouterr().err


def test_hero_offset_from_a_recording(sample, tmp_path, capsys):
    bundle = tmp_path / "calib.yaml"
    shutil.copy(sample / "calib.yaml", bundle)
    assert main(["hero-offset", "--bundle", str(bundle), "--replay", str(sample), "--team", "blue", "--actual", "10.0", "--force", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    # the measured range is the median over frames of |blue_1 - red_outpost|: compare with the truth's own median
    from radarcal.field import FieldModel

    fm = FieldModel.from_dict(load_bundle(bundle).field_model)
    outpost = fm.landmarks["red_outpost"][:2]
    truth = [np.hypot(*(np.array(r["p_field"][:2]) - outpost)) for ln in (sample / "truth.jsonl").read_text().splitlines()
             for r in json.loads(ln)["robots"] if r["label"] == "blue_1" and r["visible"]]  # fmt: skip
    assert s["frames_with_hero"] > 100 and abs(s["measured_m"] - np.median(truth)) < 0.15
    assert s["hero_range_offset_m"] == pytest.approx(10.0 - s["measured_m"])
    assert main(["hero-offset", "--bundle", str(bundle), "--replay", str(sample), "--team", "blue", "--marker", "blue_base", "--force", "--json"]) == 0
    s2 = json.loads(capsys.readouterr().out)
    assert s2["actual_m"] == pytest.approx(np.hypot(*(fm.landmarks["blue_base"][:2] - outpost)))
    assert main(["hero-offset", "--bundle", str(bundle), "--replay", str(sample), "--marker", "nope", "--team", "blue"]) == 2
    assert "no landmark 'nope'" in capsys.readouterr().err
    assert main(["hero-offset", "--bundle", str(bundle), "--measured", "3"]) == 2  # neither --actual nor --marker


def test_run_survives_corrupt_clouds_and_images(sample, tmp_path, capsys):
    rep = tmp_path / "rep"
    shutil.copytree(sample, rep)
    (rep / "clouds" / "000010.pcd").write_bytes(b"garbage")
    (rep / "clouds" / "000011.pcd").write_bytes(b"")
    (rep / "images" / "000010.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    from radarcal.runtime.synthetic_onnx import make_fixed_boxes_model

    model = tmp_path / "m.onnx"
    row = np.zeros(7, np.float32)
    row[:5] = [320, 300, 20, 20, 0.9]
    row[5] = 1
    make_fixed_boxes_model(model, row[None], 640, ["blue_1", "red_3"])
    assert main(["run", "--replay", str(rep), "--json", "--max-frames", "40"]) == 0
    s = json.loads(capsys.readouterr().out)
    # (the first frames have no robot in the default LiDAR-first mode: 6 robots x the 2 frames before a third box)
    assert s["frames"] == 40 and s["clouds"] == 12 and s["accuracy"]["missing"] <= 12
    assert s["skipped_inputs"] == 2 and s["skipped_by_reason"] == {"unreadable cloud file": 2}  # counted per run (was a global list)
    assert main(["run", "--replay", str(rep), "--detector", str(model), "--json", "--max-frames", "8"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["frames"] == 8 and s["bad_frames"] == 1 and "000010.jpg" in cap.err


def test_run_without_field_model_uses_flat_ground(sample, tmp_path, capsys):
    import yaml

    d = yaml.safe_load((sample / "calib.yaml").read_text())
    d["field"] = None
    b = tmp_path / "nofield.yaml"
    b.write_text(yaml.safe_dump(d))
    assert main(["run", "--replay", str(sample), "--bundle", str(b), "--no-lidar", "--team", "blue", "--json", "--max-frames", "90"]) == 0
    s = json.loads(capsys.readouterr().out)
    acc = s["accuracy"]
    # the sample's robots mostly stay on the ground: the plane z = 0 locates them; no outpost -> no hero range
    assert acc["missing"] == 0 and acc["median_m"] < 0.3 and s["lidar"] is None


def test_run_video_with_a_bag_and_an_explicit_clock_offset(sample, tmp_path, capsys):
    """Camera from an image folder (times from 0), clouds from a ROS1 bag stamped on another clock (1.7e9 s): the
    default offset 0 is refused with a clear error, --cloud-time-offset -1.7e9 and 'first' pair the same clouds."""
    from bag_writer import write_ros1_livox_bag

    from radarcal.io.cloud_sources import FolderCloudSource

    clouds = list(FolderCloudSource(items=[(t, p) for t, p in FolderCloudSource(sample / "clouds").items if t < 4.0]))
    bag = write_ros1_livox_bag(tmp_path / "c.bag", [c.points for c in clouds], [1700000000.0 + c.t for c in clouds], refl=[np.zeros(len(c), np.uint8) for c in clouds])
    args = ["run", "--video", str(sample / "images"), "--clouds", str(bag), "--detections", str(sample / "detections.jsonl"), "--bundle", str(sample / "calib.yaml"),
            "--max-frames", "30", "--json", "--quiet"]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 2
    assert "the two clocks differ" in capsys.readouterr().err
    got = {}
    for offset in ("-1700000000", "first"):
        assert main([*args, "--cloud-time-offset", offset]) == 0
        got[offset] = json.loads(capsys.readouterr().out)
    a, b = got["-1700000000"], got["first"]
    assert a["clouds"] == b["clouds"] > 10 and a["skipped_inputs"] == 0
    assert a["robot_frames"]["depth"] > 0 and a["robot_frames"] == b["robot_frames"]
    assert main([*args, "--cloud-time-offset", "soon"]) == 2

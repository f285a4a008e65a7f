"""`radarcal run` marking options through the CLI: bad values are one-line errors; over a pseudo-terminal the link
carries the 0x0121 request of a policy, the sentry message with the roster, and the sentry's replies count."""

from __future__ import annotations

import json
import os
import select
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
        pytest.skip("datasets/sample_replay missing (python datasets/make_sample.py)")
    return SAMPLE


@pytest.mark.parametrize("argv,msg", [
    (["--dv-on-key", "F12"], "--dv-on-key"),
    (["--dv-enemies-in-half", "0"], "--dv-enemies-in-half"),
    (["--dv-at", "-3"], "--dv-at"),
])  # fmt: skip
def test_bad_marking_options_are_one_line_exit_2(sample, argv, msg, capsys):
    assert main(["run", "--replay", str(sample), "--max-frames", "1", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {msg}") and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_dv_policy_and_sentry_link_over_a_pty(sample, capsys):
    master, slave = os.openpty()
    os.set_blocking(master, False)
    parser = rp.FrameParser()
    got: list[rp.Frame] = []
    stop = threading.Event()

    def referee():  # we are red (9); the match runs, 400 s remaining; the sentry (7) talks to us; one DV chance
        t0 = time.monotonic()
        while not stop.is_set():
            r, _, _ = select.select([master], [], [], 0.05)
            if r:
                try:
                    got.extend(parser.feed(os.read(master, 4096)))
                except (BlockingIOError, OSError):
                    pass
            try:
                os.write(master, rp.pack_frame(rp.CMD_ROBOT_STATUS, bytes([9, 1]) + bytes(11)) + rp.pack_frame(rp.CMD_GAME_STATUS, bytes([0x41, 144, 1]) + bytes(8))
                         + rp.pack_frame(rp.CMD_RADAR_INFO, bytes([1 | 8])) + rp.pack_frame(rp.CMD_INTERACTION, rp.interaction_payload(0x0222, 7, 9, b"ok")))  # fmt: skip
            except OSError:
                pass
            if time.monotonic() - t0 > 60:
                break

    th = threading.Thread(target=referee, daemon=True)
    th.start()
    try:
        time.sleep(0.2)
        code = main(["run", "--replay", str(sample), "--serial", os.ttyname(slave), "--season", "2026", "--dv-at", "15", "--speed", "4", "--json", "--max-frames", "90"])
        time.sleep(0.3)
    finally:
        stop.set()
        th.join(2)
        os.close(master)
        os.close(slave)
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and parser.stats.bad_crc16 == parser.stats.bad_crc8 == 0
    inter = [rp.parse_interaction(f.data) for f in got if f.cmd_id == rp.CMD_INTERACTION]
    dv = [i for i in inter if i["sub_id"] == rp.SUB_RADAR_CMD]
    assert dv and all(i["receiver"] == rp.SERVER_ID and i["sender"] == 9 and i["content"] == bytes([1, 0]) + bytes(6) for i in dv)  # 420 - 400 >= 15
    assert s["marking"]["double_vulnerability"][0]["counter"] == 1
    sentry = [i for i in inter if i["sub_id"] == 0x0200]
    assert sentry and all(i["receiver"] == 7 and len(i["content"]) == 15 + 6 * i["content"][14] for i in sentry)
    assert max(i["content"][14] for i in sentry) >= 1  # the roster's enemies ride along
    assert s["marking"]["sentry_rx"] > 0
    maps = [f for f in got if f.cmd_id == rp.CMD_MAP]
    assert maps and all(len(f.data) == 48 for f in maps)

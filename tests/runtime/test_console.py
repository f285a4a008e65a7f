"""The live console of ``radarcal run --ui``: security of the server (no browser needed) and, in a real headless
Chromium, the page against the loop's own ``tracks.jsonl`` (rate, latency, robot table, screenshot)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.runtime.console.live import LiveConsole
from radarcal.runtime.console.server import LatestSlot, WebServer, parse_bind

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "datasets" / "sample_replay"


def _req(url: str, method: str = "GET", body: dict | None = None, headers: dict | None = None) -> tuple[int, dict | bytes]:
    data = None if body is None else json.dumps(body).encode()
    r = urllib.request.Request(url, data=data, method=method, headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(r, timeout=5) as resp:
            raw = resp.read()
            return resp.status, (json.loads(raw) if resp.headers.get("Content-Type", "").startswith("application/json") else raw)
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


@pytest.fixture
def console():
    logs: list[str] = []
    srv = WebServer("127.0.0.1", 0, log=logs.append, hold_s=30)
    con = LiveConsole(srv)
    srv.start()
    yield con, srv, logs
    srv.close()


def test_default_bind_is_loopback():
    assert parse_bind("8080") == ("127.0.0.1", 8080)
    assert parse_bind(":8080") == ("127.0.0.1", 8080)
    assert parse_bind("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_bind("[::1]:9000") == ("::1", 9000)
    with pytest.raises(InputError):
        parse_bind("localhost:http")
    with pytest.raises(InputError):
        parse_bind("70000")
    srv = WebServer(port=0, log=lambda s: None)
    try:
        assert srv.host == "127.0.0.1" and srv.loopback
    finally:
        srv.httpd.server_close()


def test_actions_need_token_session_and_a_fresh_sequence(console):
    con, srv, logs = console
    base = srv.url
    act = base + "api/action/double_vulnerability"
    # no token, wrong token: refused, nothing queued
    assert _req(act, "POST", {"session": "x", "seq": 1})[0] == 401
    assert _req(act, "POST", {"session": "x", "seq": 1}, {"X-Radarcal-Token": "wrong" + srv.token})[0] == 401
    assert _req(base + "api/claim", "POST", {}, {"X-Radarcal-Token": srv.token[:-1]})[0] == 401
    # the right token but no session (never claimed): refused
    tok = {"X-Radarcal-Token": srv.token}
    assert _req(act, "POST", {"session": "guess", "seq": 1}, tok)[0] == 409
    assert not con.requests
    st, j = _req(base + "api/claim", "POST", {}, tok)
    assert st == 200
    sess = j["session"]
    st, j = _req(act, "POST", {"session": sess, "seq": 1, "args": {"why": "test"}}, tok)
    assert st == 200 and j["queued"] and len(con.requests) == 1 and con.requests[0]["args"] == {"why": "test"}
    # the same request again (replayed), an older sequence, a non-integer one: refused
    assert _req(act, "POST", {"session": sess, "seq": 1}, tok)[0] == 409
    assert _req(act, "POST", {"session": sess, "seq": 0}, tok)[0] == 409
    assert _req(act, "POST", {"session": sess, "seq": "2"}, tok)[0] == 409
    assert _req(act, "POST", {"session": sess, "seq": 2}, tok)[0] == 200
    # a second client (even with the token) cannot take the controls while the first is active
    assert _req(base + "api/claim", "POST", {}, tok)[0] == 409
    # ... nor act with a made-up session
    assert _req(act, "POST", {"session": sess + "x", "seq": 9}, tok)[0] == 409
    assert len(con.requests) == 2
    # unknown actions and garbage bodies are refused too
    assert _req(base + "api/action/format_disk", "POST", {"session": sess, "seq": 10}, tok)[0] == 404
    r = urllib.request.Request(act, data=b"not json", method="POST", headers=tok)
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(r, timeout=5)
    assert e.value.code == 400
    # every refusal is logged with its reason
    assert len(srv.refusals) == 11 and len(logs) == 11
    assert all(line.startswith("console: refused ") for line in logs)
    assert any("replayed" in r["why"] for r in srv.refusals) and any("second client" in r["why"] for r in srv.refusals)


def test_host_and_origin_checks(console):
    _, srv, _ = console
    assert _req(srv.url, headers={"Host": "attacker.example:80"})[0] == 403  # DNS rebinding
    st, _ = _req(srv.url + "api/claim", "POST", {}, {"X-Radarcal-Token": srv.token, "Origin": "http://attacker.example"})
    assert st == 403
    assert _req(srv.url)[0] == 200  # loopback: read-only views without the token


def test_not_loopback_every_view_needs_the_token():
    srv = WebServer("0.0.0.0", 0, log=lambda s: None)
    LiveConsole(srv)
    srv.start()
    try:
        url = f"http://127.0.0.1:{srv.port}/"
        assert not srv.loopback
        assert _req(url)[0] == 401
        assert _req(url + "api/field")[0] == 401
        assert _req(url + "?token=" + srv.token)[0] == 200
    finally:
        srv.close()


def test_publisher_never_waits_for_a_stalled_page(console):
    """A client that opens the stream and never reads, and a flood of bad requests, do not slow ``on_frame``."""
    import socket
    import threading

    con, srv, _ = console

    class Res:
        def __init__(self, i):
            self.i = i

        def to_dict(self):
            return {"t": self.i / 30, "frame": f"{self.i:06d}", "robots": [{"label": "red_1", "x": 1.0, "y": 2.0}] * 200, "pad": "x" * 20000}

    stalled = socket.create_connection(("127.0.0.1", srv.port))
    stalled.sendall(f"GET /api/events HTTP/1.1\r\nHost: 127.0.0.1:{srv.port}\r\n\r\n".encode())  # then never read
    stop = threading.Event()

    def flood():
        while not stop.is_set():
            _req(srv.url + "api/action/double_vulnerability", "POST", {"seq": 1}, {"X-Radarcal-Token": "bad"})

    th = threading.Thread(target=flood, daemon=True)
    th.start()
    times = []
    for i in range(3000):
        tic = time.perf_counter()
        con.on_frame(i, Res(i))
        times.append(time.perf_counter() - tic)
    stop.set()
    th.join(5)
    stalled.close()
    assert con.results.seq == 3000
    assert np.percentile(times, 99) < 2e-3 and max(times) < 0.05, (np.percentile(times, 99), max(times))


def test_latest_slot_drops_old_values():
    s = LatestSlot()
    for i in range(5):
        s.put(i)
    assert s.get_newer(0, 0.01) == (5, 4)
    assert s.get_newer(5, 0.01) == (5, None)


# --- in the browser ------------------------------------------------------------------------------------------------------
def _start_run(tmp_path: Path, extra: list[str]) -> tuple[subprocess.Popen, str, str]:
    out = tmp_path / "tracks.jsonl"
    cmd = [sys.executable, "-m", "radarcal", "run", "--replay", str(SAMPLE), "--ui", "127.0.0.1:0", "--out", str(out), "--quiet", "--json", *extra]
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1"}
    p = subprocess.Popen(cmd, cwd=REPO, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 60
    while time.time() < deadline:
        line = p.stderr.readline()
        m = re.search(r"console: (http://\S+)#token=(\S+)", line or "")
        if m:
            return p, m.group(1), m.group(2)
        if not line and p.poll() is not None:
            break
    p.kill()
    raise AssertionError("radarcal run --ui did not announce its address: " + (p.stderr.read() or ""))


def _table_rows(driver) -> tuple[str, list[list[str]]]:
    return driver.execute_script(
        "return [document.getElementById('frame').textContent,"
        " Array.from(document.querySelectorAll('#robots tbody tr')).map(tr => Array.from(tr.cells).map(c => c.textContent))];"
    )


@pytest.mark.skipif(not (SAMPLE / "meta.json").is_file(), reason="datasets/sample_replay missing")
def test_console_in_chromium_follows_the_replay(browser, screenshot, tmp_path):
    p, url, token = _start_run(tmp_path, ["--max-frames", "240"])
    msg = shot = None
    try:
        browser.get(url + "#token=" + token)
        assert browser.title == "radarcal console"
        samples = []
        t_end = time.time() + 20
        while time.time() < t_end and p.poll() is None:
            time.sleep(0.3)
            samples.append(_table_rows(browser))
            if len(samples) == 3:  # the operator's trigger, from the page with the token of this run
                browser.find_element("id", "dvbtn").click()
            if len(samples) == 6:
                msg = browser.find_element("id", "actionmsg").text
                shot = screenshot(browser, "console_live")
            stats = browser.execute_script("return window.__console;")
    finally:
        out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    con = json.loads(out)["console"]
    assert con["actions"] == 1 and con["refused_requests"] == 0 and con["messages_sent"] >= len(stats["log"])
    # the page was live the whole replay: >= 10 updates per second
    log = stats["log"]
    span = (log[-1]["shown"] - log[0]["shown"]) / 1e3
    rate = (len(log) - 1) / span
    lat_all = np.array([e["latency"] for e in log])
    lat = np.array([e["latency"] for e in log if e["shown"] > log[0]["shown"] + 1000])  # steady state: after the page's first second
    print(f"\nconsole: {len(log)} updates over {span:.1f} s = {rate:.1f} Hz; frame -> page latency median {np.median(lat):.0f} ms, "
          f"p95 {np.percentile(lat, 95):.0f} ms, max {lat.max():.0f} ms (first second included: p95 {np.percentile(lat_all, 95):.0f} ms)")  # fmt: skip
    assert rate >= 10.0
    assert np.percentile(lat, 95) < 200.0 and np.median(lat) < 100.0
    # the robot table matches what the loop wrote to tracks.jsonl for the frame it shows
    tracks = {}
    for line in (tmp_path / "tracks.jsonl").read_text().splitlines():
        d = json.loads(line)
        tracks[d["frame"]] = {r["label"]: r for r in d["robots"]}
    checked = 0
    for frame, rows in samples:
        if frame not in tracks or not rows:
            continue
        want = tracks[frame]
        assert sorted(r[0] for r in rows) == sorted(want), frame
        for r in rows:
            w = want[r[0]]
            assert abs(float(r[1]) - w["x"]) <= 0.0051 and abs(float(r[2]) - w["y"]) <= 0.0051 and r[3] == w["source"]
        checked += 1
    assert checked >= 5, samples
    assert msg.startswith("trigger sent") and '"queued":true' in msg
    # the screenshot shows the page (minimap drawn, camera frame loaded), not a blank window
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[0] > 500 and img.std() > 20


def test_cli_bad_ui_arguments_are_one_line_errors(tmp_path, capsys):
    import socket

    from radarcal.cli.main import main

    assert main(["run", "--replay", str(SAMPLE), "--ui", "nonsense", "--quiet"]) == 2
    assert "error: --ui: expected [HOST:]PORT" in capsys.readouterr().err
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    try:
        assert main(["run", "--replay", str(SAMPLE), "--ui", str(busy.getsockname()[1]), "--quiet", "--out", str(tmp_path / "t.jsonl")]) == 2
        assert "error: --ui: cannot listen on 127.0.0.1:" in capsys.readouterr().err
    finally:
        busy.close()
    assert not (tmp_path / "t.jsonl").exists()  # stopped before the loop wrote anything
    b = tmp_path / "b.yaml"
    b.write_bytes((SAMPLE / "calib.yaml").read_bytes())
    before = b.read_bytes()
    assert main(["field-pnp", "-b", str(b), "--ui", "0"]) == 2
    assert "error: --ui: needs --image" in capsys.readouterr().err
    assert b.read_bytes() == before


def test_the_controls_are_held_while_the_page_is_open():
    import socket

    srv = WebServer("127.0.0.1", 0, log=lambda s: None, hold_s=0.3)
    srv.start()
    try:
        tok = {"X-Radarcal-Token": srv.token}
        sess = _req(srv.url + "api/claim", "POST", {}, tok)[1]["session"]
        page = socket.create_connection(("127.0.0.1", srv.port))  # the first page's hold stream
        page.sendall(f"GET /api/hold?session={sess} HTTP/1.1\r\nHost: 127.0.0.1:{srv.port}\r\n\r\n".encode())
        assert b"200" in page.recv(200)
        time.sleep(0.6)  # idle longer than hold_s, but its page is open
        assert _req(srv.url + "api/claim", "POST", {}, tok)[0] == 409
        page.close()  # the page is gone: after hold_s a new page (reload) may take the controls
        time.sleep(3.0)  # the server notices within two pings (1 s apart)
        st, j = _req(srv.url + "api/claim", "POST", {}, tok)
        assert st == 200 and j["session"] != sess
        # the old session is dead
        assert _req(srv.url + "api/action/x", "POST", {"session": sess, "seq": 5}, tok)[0] == 404  # unknown action first
    finally:
        srv.close()

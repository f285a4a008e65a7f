"""`radarcal report` bad input at the command line: one line naming the file, exit 2, nothing written."""

from __future__ import annotations

import json

import numpy as np

from radarcal.bundle import Bundle, save_bundle
from radarcal.camera import Camera
from radarcal.cli.main import main


def _bundle(tmp_path):
    b = Bundle(path=tmp_path / "calib.yaml")
    b.set_camera("cam0", Camera((640, 480), [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]], np.zeros(5)))
    save_bundle(b, b.path)
    return b.path


def _truth(tmp_path):
    p = tmp_path / "truth.jsonl"
    p.write_text("".join(json.dumps({"t": 0.1 * i, "robots": [{"label": "blue_4", "x": 1.0 + i, "y": 2.0}]}) + "\n" for i in range(5)))
    return p


def test_truth_without_tracks_is_an_error(tmp_path, capsys):
    bundle, truth, out = _bundle(tmp_path), _truth(tmp_path), tmp_path / "r.html"
    before = bundle.read_bytes()
    assert main(["report", str(bundle), "-o", str(out), "--truth", str(truth)]) == 2
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {truth}: --truth needs --tracks"), cap.err
    assert "Traceback" not in cap.err and not out.exists() and bundle.read_bytes() == before
    # with --tracks it is used: the run section has the error over time
    assert main(["report", str(bundle), "-o", str(out), "--tracks", str(truth), "--truth", str(truth), "--json", "--dpi", "30"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["sections"][-1] == "Run: tracks" and s["figures"] == 2  # minimap + error over time


def test_empty_track_file_is_an_error(tmp_path, capsys):
    bundle, out = _bundle(tmp_path), tmp_path / "r.html"
    empty = tmp_path / "empty.jsonl"
    empty.write_text("")
    assert main(["report", str(bundle), "-o", str(out), "--tracks", str(empty)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {empty}: no robot positions in the track file") and not out.exists()

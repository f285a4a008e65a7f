"""The embedded sample replay (make demo) regenerates bit for bit from its seed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

def test_sample_replay_regenerates_identically():
    proc = subprocess.run([sys.executable, str(REPO / "datasets" / "make_sample.py"), "--check"], capture_output=True, text=True, timeout=600, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("identical"), proc.stdout

"""The documented notebook command (docs/report.md) works in the project's environment: ``jupyter nbconvert --to html
--execute notebooks/X.ipynb`` with the venv's own ``python3`` kernel (no test kernelspec), run as a user would."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
JUPYTER = Path(sys.executable).parent / "jupyter"


@pytest.mark.parametrize("name", ["field_report", pytest.param("intrinsics_report", marks=pytest.mark.slow), pytest.param("lidar_camera_report", marks=pytest.mark.slow)])
def test_documented_nbconvert_command(tmp_path, name):
    if not JUPYTER.exists() or shutil.which("jupyter-nbconvert", path=str(JUPYTER.parent)) is None:
        pytest.skip(f"nbconvert is not installed in {JUPYTER.parent} (pip install -e '.[test]')")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RADARCAL_REPORT_", "JUPYTER_PATH"))}
    env.update({"MPLBACKEND": "Agg", "RADARCAL_REPORT_WORKDIR": str(tmp_path), "PYTHONPATH": str(REPO), "PATH": f"{JUPYTER.parent}{os.pathsep}{env.get('PATH', '')}"})
    proc = subprocess.run(["jupyter", "nbconvert", "--to", "html", "--execute", f"notebooks/{name}.ipynb", "--output-dir", str(tmp_path / "html")],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    html = (tmp_path / "html" / f"{name}.html").read_text(encoding="utf-8")
    assert html.count("data:image/png;base64") >= 3 and "Traceback" not in html

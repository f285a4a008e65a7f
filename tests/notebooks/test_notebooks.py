"""Execute every report notebook headless (nbclient) on generated data, and on the real data sets when present.

The kernel is this interpreter (``sys.executable``), registered for the test in a temporary ``JUPYTER_PATH``, so the
tests work in a fresh venv with ipykernel installed and never pick up another Python. ``PYTHONPATH`` points at this
checkout so the notebooks import the radarcal under test.
"""

from __future__ import annotations

import base64
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

import nbformat  # noqa: E402
from nbclient import NotebookClient  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
NOTEBOOKS = REPO / "notebooks"
KERNEL = "radarcal-test-python3"


@pytest.fixture
def kernel_env(tmp_path, monkeypatch):
    """A kernelspec running this interpreter, visible through JUPYTER_PATH; headless matplotlib."""
    spec_dir = tmp_path / "jupyter" / "kernels" / KERNEL
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(json.dumps({"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"], "display_name": "radarcal test", "language": "python"}))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(REPO)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])))
    monkeypatch.setenv("PYDEVD_DISABLE_FILE_VALIDATION", "1")
    for k in [k for k in os.environ if k.startswith("RADARCAL_REPORT_")]:
        monkeypatch.delenv(k)
    monkeypatch.setenv("RADARCAL_REPORT_WORKDIR", str(tmp_path))  # generated data goes to the test's tmp dir
    return monkeypatch


def run_notebook(name: str, workdir: Path, timeout: int = 180) -> list[bytes]:
    """Execute ``notebooks/<name>`` top to bottom; return the PNG images it displayed. Raises on any cell error."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    NotebookClient(nb, timeout=timeout, kernel_name=KERNEL, resources={"metadata": {"path": str(workdir)}}).execute()
    pngs = []
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert out.get("output_type") != "error", f"{name}: {out.get('ename')}: {out.get('evalue')}"
            if out.get("output_type") == "stream":
                assert out.get("name") != "stderr" or "Traceback" not in out.get("text", ""), out.get("text")
            data = out.get("data", {})
            if "image/png" in data:
                pngs.append(base64.b64decode(data["image/png"]))
    return pngs


def assert_figures(pngs: list[bytes], at_least: int) -> None:
    import cv2

    assert len(pngs) >= at_least, f"{len(pngs)} figures, expected at least {at_least}"
    for png in pngs:
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
        assert img.std() > 5, "a blank figure"


# --- intrinsics ---------------------------------------------------------------------------------------------------------
def test_intrinsics_notebook_generated(kernel_env, tmp_path):
    # rendered board images -> radarcal intrinsics -> parameter table, per-view, vectors (all + worst view over its
    # image), histogram, coverage, uncertainty, distortion, cross-validation, solved vs true camera
    assert_figures(run_notebook("intrinsics_report.ipynb", tmp_path), 10)


@pytest.mark.shared
def test_intrinsics_notebook_opencv_stereo_chessboard(kernel_env, tmp_path, shared):
    data = shared("opencv_stereo_chessboard")
    from radarcal.cli.main import main as cli

    bundle = tmp_path / "calib.yaml"
    images = sorted(str(p) for p in data.glob("left*.jpg"))
    assert cli(["intrinsics", *images, "--cols", "9", "--rows", "6", "--square", "0.025", "--camera", "cam0", "--bundle", str(bundle), "--json"]) == 0
    kernel_env.setenv("RADARCAL_REPORT_BUNDLE", str(bundle))
    kernel_env.setenv("RADARCAL_REPORT_CAMERA", "cam0")
    assert_figures(run_notebook("intrinsics_report.ipynb", tmp_path), 9)  # + the worst view over its image


# --- field --------------------------------------------------------------------------------------------------------------
def test_field_notebook_generated(kernel_env, tmp_path):
    # field + picks + two error maps (LiDAR, ground) + minimap + error over time
    assert_figures(run_notebook("field_report.ipynb", tmp_path), 6)


# --- lidar-camera -------------------------------------------------------------------------------------------------------
def test_lidar_camera_notebook_generated(kernel_env, tmp_path):
    # overlay before/after/truth, edge matches, residual histogram, cost profiles, σ table
    assert_figures(run_notebook("lidar_camera_report.ipynb", tmp_path), 5)


@pytest.mark.shared
def test_lidar_camera_notebook_mlcc(kernel_env, tmp_path, shared):
    """Real Livox Mid-100 head + 1280x1024 camera: intrinsics from the data set, the reference T_cam_lidar perturbed by
    3 deg / 10 cm as the start, the reference drawn and compared with."""
    data = shared("mlcc_livox_mid100_scene2")
    from radarcal.cli.main import main as cli
    from radarcal.geometry import perturb_T

    pair = json.loads((data / "calib" / "pairs_T_cam_lidar.json").read_text())["pairs"][0]
    bundle = tmp_path / "calib.yaml"
    assert cli(["bundle", "import", str(bundle), str(data / pair["intrinsics"]), "--camera", "cam0"]) == 0
    T_ref = np.asarray(pair["T_cam_lidar"], float)
    (tmp_path / "reference.json").write_text(json.dumps({"T_cam_lidar": T_ref.tolist()}))
    T0 = perturb_T(T_ref, 3.0, 0.10, np.random.default_rng(0))
    (tmp_path / "init.json").write_text(json.dumps({"T_cam_lidar": T0.tolist()}))
    for k, v in {"BUNDLE": bundle, "IMAGE": data / pair["image"], "CLOUD": data / pair["cloud"], "INIT": tmp_path / "init.json", "REFERENCE": tmp_path / "reference.json"}.items():
        kernel_env.setenv(f"RADARCAL_REPORT_{k}", str(v))
    assert_figures(run_notebook("lidar_camera_report.ipynb", tmp_path), 4)

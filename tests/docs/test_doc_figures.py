"""Audit of the figures README.md and docs/*.md quote for the real files as shipped (issue 17: KITTI, OpenCalib,
Calib-Anything, mrcal corners, TU Delft, OpenCalib lidar2lidar) and for the report: each figure (a) has the command
that reproduces it written in the docs next to it (README figures: on the doc page it links), and (b) is measured
here by running exactly that command, as the doc writes it, on the shared data set, and compared within a stated
tolerance. The quoted numbers are read from the doc text itself, so a wrong doc figure (or a command that no longer
gives it) fails. Skipped with a reason when ``../shared/datasets`` is absent.

Comparison kinds: ``value`` |measured - quoted| <= tol; ``bound`` measured <= quoted (the doc says "to 1e-4 deg",
"<= 2e-5"); ``range`` quoted low <= measured <= quoted high.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from tests.conftest import SHARED_DATASETS, shared_dataset

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class DocFigure:
    doc: str  # where the figure is quoted
    pattern: str  # regular expression over the doc's text (whitespace collapsed); its groups are the quoted numbers
    run: str  # the measurement (key of RUNS) whose result gives the values
    values: Callable[[dict], list[float]]  # the measured values, one per group (or per pair of groups for "range")
    tol: tuple[float, ...] = ()  # per value, for "value"
    kind: str = "value"  # value | bound | range
    command_doc: str | None = None  # where the command is written, when not in ``doc`` (README -> its doc page)
    window: int = 2500  # the command must be within this many characters of the figure


# --- the commands, exactly as the docs write them (whitespace collapsed, line continuations joined) ----------------
CMD = {
    "kitti_import": "radarcal bundle import b.yaml ../shared/datasets/kitti_000008/calib_000008.txt --camera cam2 --image-size 1242x375",
    "opencalib_extrinsic": "radarcal bundle set-transform b.yaml cam0 lidar0 ../shared/datasets/opencalib_road_64beam/auto/top_center_lidar-to-center_camera-extrinsic.json",
    "mrcal": "radarcal intrinsics --corners ../shared/datasets/mrcal_nikon_d750_samyang12mm_fisheye_corners/corners.vnl --image-size 6016x4016 --cols 10 --rows 10 --square 0.077 --model pinhole8 -b m.yaml",
    "tudelft": "radarcal radar-lidar ../shared/datasets/tudelft_msc_example/optimization_example_data --bundle tud.yaml",
    "tudelft_planar": "radarcal radar-lidar ../shared/datasets/tudelft_msc_example/optimization_example_data --bundle tud_planar.yaml --model planar",
    "opencalib_l2l": "radarcal radar-lidar ../shared/datasets/opencalib_lidar2lidar_0001 --bundle oc.yaml --lidar-tolerance 0.5,0.05",
    "kitti_import_k": "radarcal bundle import k.yaml ../shared/datasets/kitti_000008/calib_000008.txt --camera cam2 --image-size 1242x375",
    "kitti_refine": ("radarcal lidar-camera -b k.yaml --camera cam2 --lidar lidar0 --image ../shared/datasets/kitti_000008/000008.png "
                     "--cloud ../shared/datasets/kitti_000008/000008.bin --init T0.json --refine --lidar-edges intensity --rotation-only "
                     "--image-edges canny --image-edge-min-px 20 --search-deg 3"),  # fmt: skip
    "left_intrinsics": 'radarcal intrinsics "../shared/datasets/opencv_stereo_chessboard/left*.jpg" --cols 9 --rows 6 --square 0.025 -b left.yaml',
    "left_report": "radarcal report left.yaml -o left.html",
    "stereo_intrinsics": ('radarcal intrinsics "../shared/datasets/opencv_stereo_chessboard/left*.jpg" --right "../shared/datasets/opencv_stereo_chessboard/right*.jpg" '
                          "--cols 9 --rows 6 --square 0.025 -b stereo.yaml"),  # fmt: skip
    "stereo_report": "radarcal report stereo.yaml -o stereo.html",
}


def _run(cmd: str, cwd: Path, expect: tuple[int, ...] = (0,)) -> tuple[int, dict]:
    """``cmd`` as written in the doc, in ``cwd``, with ``../shared/datasets`` where this checkout has it, plus
    ``--json``: (exit code, the JSON summary)."""
    from radarcal.cli.main import main

    args = [a.replace("../shared/datasets", str(SHARED_DATASETS)) for a in shlex.split(cmd)[1:]] + ["--json"]
    out = io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out):
        code = main(args)
    assert code in expect, (cmd, code)
    return code, json.loads(out.getvalue())


def _kitti_import(d: Path) -> dict:
    from radarcal import geometry
    from radarcal.bundle import load_bundle
    from radarcal.io import read_cloud

    k = shared_dataset("kitti_000008")
    _run(CMD["kitti_import"], d)
    b = load_bundle(d / "b.yaml")
    T = b.T("cam2", "lidar0")
    rot, trans = geometry.pose_error(T, np.array(json.loads((k / "calib_000008.json").read_text())["T_cam2_lidar"]))
    uv, valid = b.camera("cam2").project(geometry.transform_points(T, read_cloud(k / "000008.bin").points))
    inside = valid & (uv[:, 0] >= 0) & (uv[:, 0] <= 1242) & (uv[:, 1] >= 0) & (uv[:, 1] <= 375)
    return {"rot_deg": rot, "trans_um": trans * 1e6, "n_inside": int(inside.sum()), "n": len(inside)}


def _opencalib_extrinsic(d: Path) -> dict:
    from radarcal.bundle import load_bundle

    f = shared_dataset("opencalib_road_64beam") / "auto" / "top_center_lidar-to-center_camera-extrinsic.json"
    _run(CMD["opencalib_extrinsic"], d)
    as_shipped = np.array(json.loads(f.read_text())["top_center_lidar-to-center_camera-extrinsic"]["param"]["sensor_calib"]["data"], float)
    return {"max_change": float(np.abs(load_bundle(d / "b.yaml").T("cam0", "lidar0") - as_shipped).max())}


def _mrcal(d: Path) -> dict:
    shared_dataset("mrcal_nikon_d750_samyang12mm_fisheye_corners")
    _, s = _run(CMD["mrcal"], d)
    c = s["cameras"][0]
    K = np.array(c["K"])
    return {"fx": K[0, 0], "cx": K[0, 2], "cy": K[1, 2], "rms": c["rms_px"], "dropped": c["corners_dropped"]}


def _radar(key: str) -> Callable[[Path], dict]:
    def measure(d: Path) -> dict:
        shared_dataset("tudelft_msc_example")
        _, s = _run(CMD[key], d)
        r = s["radars"]["radar"] if "radar" in s["radars"] else next(iter(s["radars"].values()))
        return {"yaw_deg": abs(r["rpy_deg"][2]), "mount_m": r["mount_height_m"], "rms_cm": r["residual"]["rms_m"] * 100, "n": r["residual"]["n"],
                "holdout_cm": r["residual"]["holdout_rms_m"] * 100}  # fmt: skip

    return measure


def _opencalib_l2l(d: Path) -> dict:
    shared_dataset("opencalib_lidar2lidar_0001")
    _, s = _run(CMD["opencalib_l2l"], d)
    out = {}
    for n, v in s["lidars"].items():
        out[n] = {"f0": v["initial_fitness"], "f1": v["fitness"], "e0": v["initial_rmse_m"], "e1": v["inlier_rmse_m"], "st_cm": v["worst_translation"]["sigma_m"] * 100,
                  "sr_deg": v["worst_rotation"]["sigma_deg"]}  # fmt: skip
    return out


def _kitti_refine(d: Path) -> dict:
    from radarcal import geometry

    k = shared_dataset("kitti_000008")
    ref = np.array(json.loads((k / "calib_000008.json").read_text())["T_cam2_lidar"])
    _run(CMD["kitti_import_k"], d)
    # T0.json: "from the data set's reference rotated 1 deg (seed 0)" (docs/lidar_camera.md)
    (d / "T0.json").write_text(json.dumps({"T_cam2_lidar": geometry.perturb_T(ref, 1.0, 0.0, np.random.default_rng(0)).tolist()}))
    before = (d / "k.yaml").read_bytes()
    code, s = _run(CMD["kitti_refine"], d, expect=(0, 1))
    return {"samples": s["refine"]["lidar_edge_samples"][0], "err_deg": geometry.pose_error(np.array(s["T_cam_lidar"]), ref)[0], "code": code,
            "converged": bool(s["refine"]["converged"]), "stored": (d / "k.yaml").read_bytes() != before}  # fmt: skip


def _report(intr: str, rep: str | None) -> Callable[[Path], dict]:
    def measure(d: Path) -> dict:
        shared_dataset("opencv_stereo_chessboard")
        _, si = _run(CMD[intr], d)
        sr = _run(CMD[rep], d)[1] if rep else {"figures": None, "bytes": 0}
        c = si["cameras"][0]
        return {"figures": sr["figures"], "mb": sr["bytes"] / 1e6, "rms": c["rms_px"], "views": c["views_used"], "noise": c["noise_px"],
                "valid_pct": c["uncertainty"]["valid_fraction"] * 100, "cv_median": c["crossval"]["diff_median_px"], "cv_max": c["crossval"]["diff_max_px"]}  # fmt: skip

    return measure


RUNS: dict[str, Callable[[Path], dict]] = {
    "kitti_import": _kitti_import, "opencalib_extrinsic": _opencalib_extrinsic, "mrcal": _mrcal, "tudelft": _radar("tudelft"),
    "tudelft_planar": _radar("tudelft_planar"), "opencalib_l2l": _opencalib_l2l, "kitti_refine": _kitti_refine,
    "left_intrinsics": _report("left_intrinsics", None), "left_report": _report("left_intrinsics", "left_report"), "stereo_report": _report("stereo_intrinsics", "stereo_report"),
}  # fmt: skip
SLOW_RUNS = {"mrcal", "kitti_refine", "left_intrinsics", "left_report", "stereo_report"}  # > 10 s each on the shared machine
COMMANDS_OF_RUN = {"kitti_refine": ("kitti_import_k", "kitti_refine"), "left_report": ("left_intrinsics", "left_report"),
                   "stereo_report": ("stereo_intrinsics", "stereo_report")}  # fmt: skip

N = r"([-+]?\d[\d,]*\.?\d*(?:e-?\d+)?)"  # a quoted number (1,234 / 0.5 / 1e-4)

FIGURES: list[DocFigure] = [
    # docs/bundle.md: KITTI and OpenCalib / Calib-Anything files as shipped
    DocFigure("docs/bundle.md", rf"equals the data set's T_cam2_lidar to {N} deg / {N} µm", "kitti_import", lambda m: [m["rot_deg"], m["trans_um"]], kind="bound"),
    DocFigure("docs/bundle.md", rf"all {N} points land in the image", "kitti_import", lambda m: [m["n_inside"]], tol=(0,)),
    DocFigure("docs/bundle.md", rf"re-orthonormalised \(≤ {N} change", "opencalib_extrinsic", lambda m: [m["max_change"]], kind="bound"),
    # docs/intrinsics.md: mrcal's corners file through --corners
    DocFigure("docs/intrinsics.md", rf"fx {N}, cx {N}, cy {N} \(published mrcal", "mrcal", lambda m: [m["fx"], m["cx"], m["cy"]], tol=(0.01, 0.01, 0.01)),
    DocFigure("docs/intrinsics.md", rf"RMS {N} px \(plain 4.246\), {N} of 18,597 corners dropped", "mrcal", lambda m: [m["rms"], m["dropped"]], tol=(0.0006, 0)),
    # docs/radar_lidar.md: TU Delft and OpenCalib lidar2lidar folders as shipped
    DocFigure("docs/radar_lidar.md", rf"# T_lidar_radar: rpy=\(0, 0, {N}\) deg, mount {N} m; residual {N} cm RMS over {N} \(leave-one-out {N} cm\)", "tudelft",
              lambda m: [m["yaw_deg"], m["mount_m"], m["rms_cm"], m["n"], m["holdout_cm"]], tol=(0.0006, 0.0006, 0.006, 0, 0.006)),
    DocFigure("docs/radar_lidar.md", rf"--model planar +# the patent's naive 2D: residual {N} cm RMS over 29 \(leave-one-out {N} cm\)", "tudelft_planar",
              lambda m: [m["rms_cm"], m["holdout_cm"]], tol=(0.006, 0.006)),
    DocFigure("README.md", rf"refinement: {N} cm RMS on the TU Delft example", "tudelft", lambda m: [m["rms_cm"]], tol=(0.006,), command_doc="docs/radar_lidar.md"),
    DocFigure("README.md", rf"on the TU Delft example \(naive 2D {N} cm\)", "tudelft_planar", lambda m: [m["rms_cm"]], tol=(0.006,), command_doc="docs/radar_lidar.md"),
    DocFigure("docs/radar_lidar.md", rf"# T_top_left: fitness {N} -> {N}, inlier RMSE {N} -> {N} m; worst sigma {N} cm / {N} deg", "opencalib_l2l",
              lambda m: [m["left"][k] for k in ("f0", "f1", "e0", "e1", "st_cm", "sr_deg")], tol=(0.0006, 0.0006, 0.0006, 0.0006, 0.006, 0.0006)),
    DocFigure("docs/radar_lidar.md", rf"# T_top_right: fitness {N} -> {N}, inlier RMSE {N} -> {N} m; worst sigma {N} cm / {N} deg", "opencalib_l2l",
              lambda m: [m["right"][k] for k in ("f0", "f1", "e0", "e1", "st_cm", "sr_deg")], tol=(0.0006, 0.0006, 0.0006, 0.0006, 0.006, 0.0006)),
    # docs/lidar_camera.md: KITTI 000008 in the documented single-sweep mode
    DocFigure("docs/lidar_camera.md", rf"absolute 20-unit threshold, now {N} in view", "kitti_refine", lambda m: [m["samples"]], tol=(0,)),
    DocFigure("docs/lidar_camera.md", rf"every setting tried ends {N}-{N} deg from the reference", "kitti_refine", lambda m: [m["err_deg"]], kind="range"),
    # docs/report.md: the report and the notebook read-outs of the OpenCV sample set
    DocFigure("docs/report.md", rf"takes [\d.]+ s and {N} MB \({N} figures at 96 dpi\)", "left_report", lambda m: [m["mb"], m["figures"]], tol=(0.03, 0)),
    DocFigure("docs/report.md", rf"\(two cameras \+ stereo\) {N} figures, {N} MB", "stereo_report", lambda m: [m["figures"], m["mb"]], tol=(0, 0.03)),
    DocFigure("docs/report.md", rf"RMS {N} px over {N} views, noise σ {N} px", "left_intrinsics", lambda m: [m["rms"], m["views"], m["noise"]], tol=(0.0006, 0, 0.0006)),
    DocFigure("docs/report.md", rf"the valid region \(σ < [\d.]+ px\) is {N} % of the image", "left_intrinsics", lambda m: [m["valid_pct"]], tol=(0.6,)),
    DocFigure("docs/report.md", rf"agree to {N} px median \(max {N} px", "left_intrinsics", lambda m: [m["cv_median"], m["cv_max"]], tol=(0.006, 0.06)),
]  # fmt: skip


def _text(doc: str) -> str:
    """The doc with line continuations joined, backticks dropped and whitespace collapsed."""
    t = (ROOT / doc).read_text(encoding="utf-8").replace("\\\n", " ").replace("`", "")
    return re.sub(r"\s+", " ", t)


def _num(s: str) -> float:
    return float(s.replace(",", ""))


def _fid(f: DocFigure) -> str:
    return f"{f.doc}:{f.run}:{FIGURES.index(f)}"


@pytest.mark.parametrize("fig", FIGURES, ids=_fid)
def test_figure_is_quoted_with_its_command(fig):
    """(a) The figure is in the doc as listed, and the command that reproduces it is written next to it."""
    text = _text(fig.doc)
    m = re.search(fig.pattern, text)
    assert m, f"{fig.doc}: figure not found (pattern {fig.pattern!r}): the doc changed — update the doc or this audit"
    for key in COMMANDS_OF_RUN.get(fig.run, (fig.run,)):
        cmd = re.sub(r"\s+", " ", CMD[key])
        if fig.command_doc is None:
            i = text.find(cmd)
            assert i >= 0, f"{fig.doc}: the command for {m.group(0)!r} is not written in the doc: {cmd}"
            near = [j.start() for j in re.finditer(re.escape(cmd), text)]
            assert min(abs(j - m.start()) for j in near) <= fig.window, f"{fig.doc}: {cmd!r} is not next to {m.group(0)!r}"
        else:
            assert cmd in _text(fig.command_doc), f"{fig.command_doc}: the command for {fig.doc}'s {m.group(0)!r} is not written there: {cmd}"


_CACHE: dict[str, dict] = {}


@pytest.mark.parametrize("fig", [pytest.param(f, marks=pytest.mark.slow) if f.run in SLOW_RUNS else f for f in FIGURES], ids=_fid)
def test_figure_is_what_the_command_measures(fig, tmp_path_factory):
    """(b) Running the doc's command on the shared data set gives the quoted figure within the stated tolerance."""
    m = re.search(fig.pattern, _text(fig.doc))
    assert m, f"{fig.doc}: figure not found (pattern {fig.pattern!r})"
    quoted = [_num(g) for g in m.groups()]
    if fig.run not in _CACHE:
        _CACHE[fig.run] = RUNS[fig.run](tmp_path_factory.mktemp(fig.run))
    measured = fig.values(_CACHE[fig.run])
    where = f"{fig.doc}: {m.group(0)!r}"
    if fig.kind == "value":
        assert len(measured) == len(quoted) == len(fig.tol)
        for q, v, t in zip(quoted, measured, fig.tol):
            assert abs(v - q) <= t + 1e-12, f"{where}: the command measures {v:.6g}, the doc says {q:g} (tolerance {t:g})"
    elif fig.kind == "bound":
        for q, v in zip(quoted, measured):
            assert v <= q, f"{where}: the command measures {v:.3g}, above the doc's bound {q:g}"
    else:
        lo, hi = quoted
        assert lo <= measured[0] <= hi, f"{where}: the command measures {measured[0]:.3g}, outside the doc's {lo:g}-{hi:g}"


def test_kitti_single_sweep_says_not_converged_and_stores_nothing(tmp_path):
    """docs/lidar_camera.md: 'says "NOT converged" … nothing is stored (exit 1)' for the documented command."""
    if "kitti_refine" not in _CACHE:
        _CACHE["kitti_refine"] = RUNS["kitti_refine"](tmp_path)
    r = _CACHE["kitti_refine"]
    text = _text("docs/lidar_camera.md")
    assert 'says "NOT converged"' in text and "nothing is stored (exit 1)" in text
    assert r["code"] == 1 and not r["converged"] and not r["stored"]


test_kitti_single_sweep_says_not_converged_and_stores_nothing = pytest.mark.slow(test_kitti_single_sweep_says_not_converged_and_stores_nothing)

"""Two-camera stations through the CLI: per-camera calibration accuracy and the camera cross-check, on both scene
families of ``radarcal.synth.two_camera``. Run: ``PYTHONPATH=$PWD python -m benchmarks camera_cross_check`` (10 seeds
per family) or ``python -m benchmarks.camera_cross_check --seeds N``.

Per scene: ``radarcal lidar-camera --camera camK --corners`` (family 1: 12 LiDAR-image points, 1 px, 2 cm range noise)
and ``radarcal field-pnp --camera camK --points`` (every visible landmark, 1 px clicks; family 2: rounded + t3), both
cameras, into one bundle; then ``bundle show --json``'s cross-check, and the same after replacing cam1's field pose by a
deliberately wrong one (``bundle set-transform``). Columns: pose errors against the truth; the cross-check's median /
p95 horizontal disagreement (cm), what the calibrations' σ explain (cm), pixels in cam1; flagged or not.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.bundle import load_bundle
from radarcal.cli.main import main as cli
from radarcal.synth.two_camera import two_camera_scene, write_two_camera_scene

WRONG = {"pan 0.5 deg": ([0, 0.5, 0], [0, 0, 0]), "tilt 1 deg": ([1.0, 0, 0], [0, 0, 0]), "shift 20 cm": ([0, 0, 0], [0.2, 0, 0])}


def _run(*args) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = cli([str(a) for a in args] + ["--json"])
    if code != 0:
        raise RuntimeError(f"{args[:3]} exited {code}")
    return json.loads(out.getvalue())


def _scene(family: int, seed: int, d: Path) -> dict:
    sc = two_camera_scene(family, seed)
    write_two_camera_scene(sc, d)
    b = d / "bundle.yaml"
    t0 = time.perf_counter()
    for cam in ("cam0", "cam1"):
        if family == 1:
            _run("lidar-camera", "-b", b, "--camera", cam, "--corners", d / f"corners_{cam}.csv")
        _run("field-pnp", "-b", b, "--camera", cam, "--points", d / f"picks_{cam}.csv")
    seconds = time.perf_counter() - t0
    bd = load_bundle(b)
    row = {"seconds": seconds, "size": "x".join(map(str, sc.cameras["cam0"].image_size))}
    for cam in ("cam0", "cam1"):
        row[f"{cam}_field"] = geometry.pose_error(bd.T(cam, "field"), sc.T_cam_field(cam))
        if family == 1:
            row[f"{cam}_lidar"] = geometry.pose_error(bd.T(cam, "lidar0"), sc.T_cam_lidar[cam])
    (c,) = _run("bundle", "show", b)["cross_check"]
    row["honest"] = c
    T1 = bd.T("cam1", "field")
    for kind, (rv, t) in WRONG.items():
        (d / "wrong.json").write_text(json.dumps((geometry.T_from_rotvec(np.radians(rv), np.array(t, float)) @ T1).tolist()))
        _run("bundle", "set-transform", b, "cam1", "field", d / "wrong.json")
        (row[kind],) = _run("bundle", "show", b)["cross_check"]
    return row


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks camera_cross_check")
    ap.add_argument("--seeds", type=int, default=10)
    args = ap.parse_args(argv)
    print("two-camera stations (cam0 wide, cam1 tele), calibrated through the CLI; errors against the truth; cross-check from `bundle show --json`")
    for family in (1, 2):
        print(f"\nfamily {family}: " + ("built-in field, LiDAR-linked (lidar-camera --corners per camera)" if family == 1 else "random fields, stereo-linked (T_cam1_cam0 with a stereo σ), no LiDAR"))
        head = f"{'seed':>4} {'image':>9} {'cam0 field °/cm':>15} {'cam1 field °/cm':>15}"
        head += f" {'cam0 lidar °/cm':>15} {'cam1 lidar °/cm':>15}" if family == 1 else ""
        head += f" {'cc med cm':>9} {'p95':>5} {'σ-expl':>6} {'px cam1':>7} {'flag':>4} | " + " | ".join(f"{k} (cm, flag)" for k in WRONG) + f" {'s':>5}"
        print(head)
        ratios, caught, false_alarms = [], {k: 0 for k in WRONG}, 0
        for seed in range(args.seeds):
            with tempfile.TemporaryDirectory() as tmp:
                r = _scene(family, seed, Path(tmp))
            c = r["honest"]
            ratios.append(c["cm"]["median"] / c["expected_cm"])
            false_alarms += bool(c["flagged"])
            line = f"{seed:>4} {r['size']:>9} " + " ".join(f"{r[f'{cam}_field'][0]:7.3f}/{100 * r[f'{cam}_field'][1]:6.2f}" for cam in ("cam0", "cam1"))
            if family == 1:
                line += " " + " ".join(f"{r[f'{cam}_lidar'][0]:7.3f}/{100 * r[f'{cam}_lidar'][1]:6.2f}" for cam in ("cam0", "cam1"))
            line += f" {c['cm']['median']:9.1f} {c['cm']['p95']:5.1f} {c['expected_cm']:6.1f} {c['px_b']['median']:7.2f} {'YES' if c['flagged'] else 'no':>4} | "
            parts = []
            for k in WRONG:
                w = r[k]
                caught[k] += bool(w["flagged"])
                parts.append(f"{w['cm']['median']:6.1f} {'YES' if w['flagged'] else 'no':>3}".rjust(len(k) + 11))
            print(line + " | ".join(parts) + f" {r['seconds']:5.1f}")
        print(f"  honest pairs flagged: {false_alarms}/{args.seeds}; median / max ratio of the disagreement to what the σ explain: "
              f"{np.median(ratios):.2f} / {max(ratios):.2f} (flag at 3x); wrong cam1 pose flagged: " + ", ".join(f"{k} {v}/{args.seeds}" for k, v in caught.items()))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))

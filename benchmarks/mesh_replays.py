"""`radarcal run` accuracy on replays whose world is the real 2024 field mesh (issue #14, #15).

    PYTHONPATH=$PWD python -m benchmarks.mesh_replays [DIR] [--seeds 2,3,5] [--frames 450] [--field-seeds 1,2,3]

The replays are ray cast against HITSZ's 2024 alignment mesh with its filter mesh's structures
(``docs/fields/hitsz_rmuc2024.field.yaml``, the meshes read from ``../shared/datasets/hitsz_rmuc_field_meshes``):

* ``radarcal synth match R --field docs/fields/hitsz_rmuc2024.field.yaml --seed S`` (visible-part boxes with jitter,
  misses, false boxes, swaps; late clouds fired point by point; T_cam_lidar off 0.3 deg / 2 cm; field pose from a
  1.5 px four-point PnP), seeds 2, 3, 5, 450 frames;
* ``radarcal synth field R --field ... --seed S`` (the second family: exact boxes, exact calibration), seeds 1, 2, 3,
  300 frames.

Each replay is run with the bundle holding (a) the built-in ``rmuc_schematic`` field (what users had: the replay's
calib.yaml with its field model replaced) and (b) the mesh field (the replay's own calib.yaml), with
``--localise box``, ``lidar`` and ``auto``. Printed: right label within 0.6 m, p95 (labelled robot-frames), median,
false robots per frame, wrong label, missing / visible. Replays are kept in DIR (re-used when present).
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "docs" / "fields" / "hitsz_rmuc2024.field.yaml"
MESH = ROOT.parent / "shared" / "datasets" / "hitsz_rmuc_field_meshes" / "24_bg2align_fix1.stl"
MODES = ("box", "lidar", "auto")


def _cli(args: list[str]) -> str:
    from radarcal.cli.main import main as cli

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli(args)
    if rc != 0:
        raise RuntimeError(f"radarcal {' '.join(args)} exited {rc}")
    return buf.getvalue()


def make_replay(out: Path, kind: str, seed: int, frames: int) -> Path:
    """A ``synth match`` / ``synth field`` replay on the mesh, plus ``calib_builtin.yaml`` (same bundle, built-in field)."""
    from radarcal.bundle import load_bundle, save_bundle
    from radarcal.field import builtin_field

    if not (out / "meta.json").is_file():
        if kind == "match":
            _cli(["synth", "match", str(out), "--field", str(FIELD), "--seed", str(seed), "--frames", str(frames), "--json"])
        else:
            _cli(["synth", "field", str(out), "--field", str(FIELD), "--seed", str(seed), "--frames", str(frames), "--image-every", "1000", "--json"])
    builtin = out / "calib_builtin.yaml"
    if not builtin.is_file():
        b = load_bundle(out / "calib.yaml")
        b.field_model = builtin_field("rmuc_schematic").to_dict()
        save_bundle(b, builtin)
    return out


def run_accuracy(replay: Path, bundle: Path, mode: str) -> dict:
    s = json.loads(_cli(["run", "--replay", str(replay), "--bundle", str(bundle), "--localise", mode, "-q", "--json"]))
    return s["accuracy"]


def _row(name: str, field: str, mode: str, a: dict) -> str:
    f = lambda v, d=3: "-" if v is None else f"{v:.{d}f}"  # noqa: E731
    return (f"| {name} | {field} | {mode} | {f(a['right_within_0.6m_pct'], 1)} % | {f(a['p95_m'], 2)} m | {f(a['median_m'])} m | "
            f"{f(a['false_per_frame'])} | {f(a['wrong_label_pct'], 2)} % | {a['missing']} / {a['visible']} |")  # fmt: skip


def main(argv: list[str]) -> int:
    args = list(argv)
    opts = {"--seeds": "2,3,5", "--frames": "450", "--field-seeds": "1,2,3", "--field-frames": "300"}
    for k in list(opts):
        if k in args:
            i = args.index(k)
            opts[k] = args[i + 1]
            del args[i : i + 2]
    if not MESH.is_file():
        print(f"skipped: {MESH} is absent (the shared HITSZ meshes)")
        return 0
    base = Path(args[0]) if args else Path(tempfile.mkdtemp(prefix="mesh_replays_"))
    base.mkdir(parents=True, exist_ok=True)
    reps = [(f"match seed {s}", "match", int(s), int(opts["--frames"])) for s in opts["--seeds"].split(",") if s]
    reps += [(f"field seed {s}", "field", int(s), int(opts["--field-frames"])) for s in opts["--field-seeds"].split(",") if s]
    print(f"replays in {base}; world = {MESH.name} (+ filter-mesh structures)")
    print("| replay | bundle field | `--localise` | right label within 0.6 m | p95 | median | false robots / frame | wrong label | missing / visible |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for name, kind, seed, frames in reps:
        t0 = time.perf_counter()
        rep = make_replay(base / f"{kind}{seed}", kind, seed, frames)
        for field, bundle in (("built-in rmuc_schematic", rep / "calib_builtin.yaml"), ("mesh hitsz_rmuc2024", rep / "calib.yaml")):
            for mode in MODES:
                a = run_accuracy(rep, bundle, mode)
                rows.append({"replay": name, "field": field, "mode": mode, **{k: a[k] for k in ("right_within_0.6m_pct", "p95_m", "median_m", "false_per_frame", "wrong_label_pct", "missing", "visible")}})
                print(_row(name, field, mode, a), flush=True)
        print(f"<!-- {name}: {time.perf_counter() - t0:.0f} s -->", flush=True)
    (base / "mesh_replays.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

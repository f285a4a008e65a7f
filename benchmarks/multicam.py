"""Several cameras in ``radarcal run`` (issue #19): a 6 mm wide + 16 mm tele station against the wide camera alone.

    PYTHONPATH=$PWD python -m benchmarks multicam        # ~10 min on 2 busy cores (replays cached in $RADARCAL_BENCH_CACHE)
    PYTHONPATH=$PWD python -m benchmarks.multicam A:4 B:13,14   # other seeds of the same families

Per seed, ``radarcal synth field --cameras cam0=6mm,cam1=16mm`` writes a two-camera replay (both 1280x1024, the
tele aimed at the far half, frames 11 ms apart, a detector whose misses, jitter and number misreads follow the box's
pixel size); the same replay runs with ``--camera cam0`` (wide alone) and with both cameras. Scored against the
generator's truth (:func:`radarcal.runtime.evaluation.band_scores`) over the robots **beyond 15 m** from the wide
camera and visible to it: p95 / median horizontal error of the entry carrying the robot's label, the correct-label
rate (the robot's own label on an entry within 0.6 m), located robot-frames — once over every entry (``predicted``
ones too) and once over the entries sent on the referee map (with evidence: a robot whose only entry is a
prediction is not located there); and over all frames the fraction in
which one robot is reported twice (two entries within 0.6 m of a robot, nearer to it than to any other; "named":
counting only the labelled entries with evidence, which go on the referee map). Beside them, over **every** visible
robot-frame beyond 15 m (an unlocated one counts as not within any error): "p95 vis", the error within which 95 % of
them are located ("inf": fewer than 95 % are located at all), and the share within 0.3 m; and per seed the tail's
make-up: the entry's source (lidar / depth / ground / predicted) and the cameras that see the robot, as the share of
the errors at or above the p95.

Family A (tuning): red station, tele aimed at (0.75 L, 0.42 W), 8 robots, seeds 1-3. Family B (held out, never
tuned on): blue station, 12 mm tele at its own aim point, 10 robots, seeds 11-12.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

FAMILIES = {
    "A": {"cameras": "cam0=6mm,cam1=16mm", "robots": 8, "station": "red", "seeds": (1, 2, 3)},
    "B": {"cameras": "cam0=6mm,cam1=12mm@19:9", "robots": 10, "station": "blue", "seeds": (11, 12)},
}


def _cli(args: list[str]) -> str:
    from radarcal.cli.main import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(args)
    if code != 0:
        raise RuntimeError(f"radarcal {' '.join(args)} -> exit {code}")
    return buf.getvalue()


def replay(cache: Path, fam: str, seed: int, frames: int = 300) -> Path:
    f = FAMILIES[fam]
    out = cache / f"multicam_{fam}_{seed}_{frames}"
    if not (out / "meta.json").is_file():
        _cli(["synth", "field", str(out), "--cameras", f["cameras"], "--frames", str(frames), "--image-every", str(frames), "--seed", str(seed),
              "--robots", str(f["robots"]), "--station", f["station"], "--overwrite", "--json"])  # fmt: skip
    return out


def score(rep: Path, cameras: str) -> dict:
    from radarcal.io.replay import open_replay_folder
    from radarcal.runtime.evaluation import band_scores

    out = rep / f"bench_{cameras.replace(',', '+')}.jsonl"
    s = json.loads(_cli(["run", "--replay", str(rep), "--camera", cameras, "--out", str(out), "--json", "-q"]))
    truth = json.loads((rep / "truth.json").read_text())
    origin = np.asarray(truth["cameras"]["cam0"]["T_field_cam"], float)[:2, 3]
    res = [json.loads(x) for x in out.read_text().splitlines()]
    b = band_scores(res, open_replay_folder(rep).truth_by_frame(), origin, 15.0, seen_by="cam0")
    b["fps"] = s["fps"]
    return b


def _selection(argv: list[str]) -> list[tuple[str, tuple[int, ...]]]:
    """``FAM:SEED[,SEED...]`` arguments (e.g. ``A:4 B:13,14``: seeds never looked at while tuning); none: the
    families' own seeds."""
    if not argv:
        return [(fam, f["seeds"]) for fam, f in FAMILIES.items()]
    out = []
    for a in argv:
        fam, _, seeds = a.partition(":")
        if fam not in FAMILIES or not seeds:
            raise SystemExit(f"benchmarks.multicam: expected FAM:SEED[,SEED] with FAM in {', '.join(FAMILIES)}, got {a!r}")
        out.append((fam, tuple(int(x) for x in seeds.split(","))))
    return out


def main(argv: list[str]) -> int:
    cache = Path(os.environ.get("RADARCAL_BENCH_CACHE") or tempfile.mkdtemp(prefix="radarcal_multicam_"))
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for fam, seeds in _selection(argv):
        for seed in seeds:
            rep = replay(cache, fam, seed)
            w, wt = score(rep, "cam0"), score(rep, "cam0,cam1")
            rows.append((fam, seed, w, wt))
            print(f"  {fam} seed {seed} done", file=sys.stderr, flush=True)
    print("robots beyond 15 m of the wide camera (visible to it); 'twice': frames reporting one robot twice (all ranges)")
    print("all: the label's entry, predicted ones too; sent: only entries with evidence (the referee map): a robot whose only entry is a prediction is not located")
    print(f"{'fam':>3} {'seed':>4} | {'p95 m wide':>10} {'wide+tele':>9} {'change':>7} | {'sent p95 wide':>13} {'w+t':>5} {'change':>7} | {'median wide':>11} {'w+t':>6} | "
          f"{'label % wide':>12} {'w+t':>5} | {'sent label % wide':>17} {'w+t':>5} | {'located wide':>12} {'w+t':>5} | {'sent wide':>9} {'w+t':>5} | "
          f"{'twice % wide':>12} {'w+t':>5} | {'named twice % wide':>18} {'w+t':>5} | {'FPS wide':>8} {'w+t':>5} | "
          f"{'p95 vis wide':>12} {'w+t':>5} | {'sent wide':>9} {'w+t':>5} | {'<0.3 m % wide':>13} {'w+t':>5} | {'sent wide':>9} {'w+t':>5}")  # fmt: skip
    for fam, seed, w, wt in rows:
        print(f"{fam:>3} {seed:>4} | {w['p95_m']:10.2f} {wt['p95_m']:9.2f} {100 * (wt['p95_m'] / w['p95_m'] - 1):+6.0f}% | "
              f"{w['p95_sent_m']:13.2f} {wt['p95_sent_m']:5.2f} {100 * (wt['p95_sent_m'] / w['p95_sent_m'] - 1):+6.0f}% | {w['median_m']:11.3f} {wt['median_m']:6.3f} | "
              f"{w['correct_label_pct']:12.1f} {wt['correct_label_pct']:5.1f} | {w['correct_label_sent_pct']:17.1f} {wt['correct_label_sent_pct']:5.1f} | "
              f"{w['located']:5d}/{w['robot_frames']:<6d} {wt['located']:5d} | {w['located_sent']:9d} {wt['located_sent']:5d} | "
              f"{w['twice_pct']:12.1f} {wt['twice_pct']:5.1f} | {w['twice_labelled_pct']:18.1f} {wt['twice_labelled_pct']:5.1f} | {w['fps']:8.1f} {wt['fps']:5.1f} | "
              f"{w['p95_visible_m']:12.2f} {wt['p95_visible_m']:5.2f} | {w['p95_visible_sent_m']:9.2f} {wt['p95_visible_sent_m']:5.2f} | "
              f"{w['within_0p3_pct']:13.1f} {wt['within_0p3_pct']:5.1f} | {w['within_0p3_sent_pct']:9.1f} {wt['within_0p3_sent_pct']:5.1f}")  # fmt: skip
    print("the sent tail (errors at or above the sent p95) by the entry's source and the cameras seeing the robot: share (entries, their p95 m)")
    for fam, seed, w, wt in rows:
        for name, b in (("wide", w), ("w+t", wt)):
            parts = sorted(b["tail_sources_sent"].items(), key=lambda kv: -kv[1][2])
            print(f"{fam:>3} {seed:>4} {name:>4}: " + "; ".join(f"{k} {100 * share:.0f} % ({m}, {q:.2f})" for k, (m, q, share) in parts))
    for fam in dict.fromkeys(f for f, *_ in rows):
        sel = [(w, wt) for f, _, w, wt in rows if f == fam]
        for key, what in (("p95_m", "all"), ("p95_sent_m", "sent")):
            r = np.array([wt[key] / w[key] for w, wt in sel])
            print(f"family {fam}: p95 ({what}) wide+tele / wide = {r.mean():.2f} (seeds {', '.join(f'{x:.2f}' for x in r)}); "
                  f"{int((r <= 0.7).sum())} of {len(r)} seeds at least 30 % lower")  # fmt: skip
        print(f"family {fam}: correct label {np.mean([w['correct_label_pct'] for w, _ in sel]):.1f} % -> {np.mean([wt['correct_label_pct'] for _, wt in sel]):.1f} %; "
              f"sent {np.mean([w['correct_label_sent_pct'] for w, _ in sel]):.1f} % -> {np.mean([wt['correct_label_sent_pct'] for _, wt in sel]):.1f} %")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""The marking configurations against the referee simulator on the replay's own clock (issue #20): one command, a table.

    PYTHONPATH=$PWD python -m benchmarks.marking_offline [DIR] [--seeds 2,3,5] [--frames 1350] [--season 2026]

The same replays and simulator as ``benchmarks/referee.py`` (``radarcal synth match``, made in DIR when missing;
:class:`radarcal.synth.referee_sim.RefereeSim`), but in one process and without a serial line: each camera frame runs
the pipeline, :class:`radarcal.runtime.marking.Marking` decides the frames, the simulator receives them at the frame's
time, advances to it and answers into the referee state. No wall clock anywhere, so a loaded machine changes the run
time, never the figures (the paced pty benchmark measures what also depends on keeping up with real time).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from benchmarks.referee import CONFIGS, MISS, SEEDS, _make, _row, take_option

DROPOUT_S = 3.0  # twice as long as the LiDAR-first tracker coasts (1.5 s): the track is lost, not bridged
FLAGS = {"--no-roster": {"roster": False, "guess": False}, "--roster": {"roster": True}, "--no-guess": {"guess": False}, "--guess": {"guess": True}}


def pick_robot(replay: Path, window: tuple[float, float], season: int, enemy: str = "blue") -> str:
    """The enemy ground robot with a slot in ``season`` that the camera and the LiDAR both see most inside ``window``."""
    import json

    from radarcal.runtime.referee_season import rules

    numbers = (set(rules(season).map_slots[0]) or {1, 2, 3, 4, 5, 7}) - {6}
    count: dict[str, int] = {}
    for line in (replay / "truth.jsonl").read_text().splitlines():
        d = json.loads(line)
        if window[0] <= d["t"] <= window[1]:
            for r in d["robots"]:
                lab = r["label"]
                if lab.startswith(enemy + "_") and int(lab.rsplit("_", 1)[1]) in numbers and r["visible"] and r["lidar_hits"] > 0:
                    count[lab] = count.get(lab, 0) + 1
    return max(sorted(count), key=lambda k: count[k])


def play(replay: Path, season: int, overrides: dict, grants: tuple[float, ...] = ()) -> tuple[dict, dict]:
    """Pipeline + Marking + RefereeSim over ``replay`` on its clock; (simulator summary, marking summary)."""
    from radarcal.bundle import load_bundle
    from radarcal.cli.lidar_field_cmd import resolve_field_pose
    from radarcal.runtime import referee as rp
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.loop import Pipeline, RunConfig, pick_frames
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.marking import Marking
    from radarcal.runtime.referee_season import rules
    from radarcal.runtime.sources import merge_by_time, open_replay
    from radarcal.synth.referee_sim import RefereeSim, Truth

    rep = open_replay(replay)
    b = load_bundle(rep.bundle)
    cam, lidar = pick_frames(b, rep.meta.get("camera"), rep.meta.get("lidar"), True)
    timing = {"cloud_sweep_s": float(rep.meta["cloud_sweep_s"]), "cloud_latency_s": float(rep.meta.get("cloud_latency_s", 0.0))} if "cloud_sweep_s" in rep.meta else {}
    cfg = RunConfig.from_bundle(b, season=season, **timing, **overrides)
    T_fc, _ = resolve_field_pose(b, cam, lidar, "auto")
    if T_fc is not None:
        b.set_transform("field", cam, T_fc, method="marking_offline")
    pipe = Pipeline(b, cam, lidar, cfg)
    dets = DetectionsFile.read(rep.detections)
    from radarcal.io.replay import open_replay_folder

    truth = Truth.from_lines(open_replay_folder(replay).truth_by_frame().values())
    sim = RefereeSim(rules(season), truth, team=str(rep.meta.get("station", "red")), dv_grants=grants)
    marking = Marking(cfg, field_length_m=pipe.field_model.size[0] if pipe.field_model is not None else 28.0)

    class SimLink:  # what run() needs of a link: state, send, snapshot
        def __init__(self):
            self.state = rp.RefereeState()
            self.out: list[tuple[int, bytes]] = []

        def send(self, cmd, data, key=0):
            self.out.append((cmd, bytes(data)))

        def snapshot(self):
            return {"connected": True, "sent": 0, "received": 0}

    link = SimLink()
    t0 = [None]

    def deliver(n, res):
        if t0[0] is None:
            t0[0] = res.t
        t = res.t - t0[0]
        for cmd, data in link.out:
            sim.receive(t, rp.Frame(cmd, data))
        link.out.clear()
        sim.advance(t)
        for cmd, data in sim.due_frames(t):
            link.state.update(rp.Frame(cmd, data))

    for cmd, data in sim.due_frames(0.0):
        link.state.update(rp.Frame(cmd, data))
    summary = run_loop(pipe, merge_by_time(rep.camera_frames(), rep.cloud_frames()), lambda f: dets.lookup(f.t, f.name), link=link, status=False,
                       on_frame=deliver, marking=marking)  # fmt: skip
    return sim.summary(), summary["marking"]


def main(argv: list[str]) -> int:
    args = list(argv)

    def opt(name: str, default: str) -> str:
        return take_option(args, name, default)

    seeds = tuple(int(s) for s in opt("--seeds", ",".join(map(str, SEEDS))).split(","))
    frames = int(opt("--frames", "1350"))
    season = int(opt("--season", "2026"))
    work = Path(args[0]) if args else Path(tempfile.mkdtemp(prefix="radarcal_marking_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    tic = time.perf_counter()
    configs = [(name, {k: v for f in flags for k, v in FLAGS[f].items()}) for name, flags in CONFIGS]
    print(f"replays in {work}; season {season}; {frames} frames per replay; seeds {seeds}; replay clock (no pacing)", flush=True)
    print("\n1. correct-mark s / % of the match vulnerable per enemy robot, and the match's total score")
    print(f"{'seed':>4s} {'robot':7s} " + " ".join(f"{c:>22s}" for c, _ in configs))
    means = {c: [0.0, 0.0, 0, 0.0] for c, _ in configs}
    for seed in seeds:
        rep = _make(work / f"seed{seed}", seed, frames)
        per = {c: play(rep, season, ov)[0] for c, ov in configs}
        first = per[configs[0][0]]
        for lb in [r["robot"] for r in first["robots"] if r["off_field_s"] < first["match_s"] / 2]:
            cells = []
            for c, _ in configs:
                r = _row(per[c], lb)
                v = r["vulnerable_frac"] or 0.0
                cells.append(f"{r['correct_s']:8.1f} s / {100 * v:5.1f} %")
                means[c][0] += r["correct_s"]
                means[c][1] += v
                means[c][2] += 1
            print(f"{seed:4d} {lb:7s} " + " ".join(f"{x:>22s}" for x in cells), flush=True)
        for c, _ in configs:
            means[c][3] += per[c]["total"]["score"]
        print(f"{seed:4d} {'score':7s} " + " ".join(f"{per[c]['total']['score']:22.0f}" for c, _ in configs), flush=True)
    print(f"{'mean':>4s} {'':7s} " + " ".join(f"{m[0] / max(m[2], 1):8.1f} s / {100 * m[1] / max(m[2], 1):5.1f} %".rjust(22) for m in means.values()))
    print(f"{'mean':>4s} {'score':7s} " + " ".join(f"{m[3] / len(seeds):22.0f}" for m in means.values()))

    print(f"\n2./3. the missed robot (the enemy robot seen most in {MISS[0]:g}-{MISS[1]:g} s; roster on): camera miss {MISS[0]:g}-{MISS[1]:g} s "
          f"with a LiDAR dropout {MISS[0]:g}-{MISS[0] + DROPOUT_S:g} s at its start (its track is lost, re-found unnamed) / truly absent")
    print(f"{'seed':>4s} {'robot':7s} {'':9s} {'miss: correct s':>16s} {'miss: wrong s':>14s} {'absent: wrong s':>16s} {'absent: wrong/match':>20s}")
    for seed in seeds:
        base = work / f"seed{seed}"
        robot = pick_robot(base, MISS, season)
        hard = _make(work / f"seed{seed}_hard_{robot}", seed, frames, ["--camera-miss", f"{robot}:{MISS[0]:g}:{MISS[1]:g}", "--lidar-miss", f"{robot}:{MISS[0]:g}:{MISS[0] + DROPOUT_S:g}"])
        absent = _make(work / f"seed{seed}_absent_{robot}", seed, frames, ["--absent", robot])
        for name, ov in (("no guess", {"guess": False}), ("guess", {"guess": True})):
            s_m, _ = play(hard, season, ov)
            s_a, _ = play(absent, season, ov)
            rm, ra = _row(s_m, robot), _row(s_a, robot)
            print(f"{seed:4d} {robot:7s} {name:9s} {rm['correct_s']:16.1f} {rm['wrong_s']:14.1f} {ra['wrong_s']:16.1f} {ra['wrong_s'] / max(s_a['match_s'], 1e-9):20.3f}", flush=True)
    base = work / f"seed{seeds[0]}"
    s, mk = play(base, season, {"dv_at_s": 20.0}, grants=(10.0, 30.0))
    d = s["double_vulnerability"]
    print(f"\n4. dv_at 20 s (chances at 10 s, 30 s): {d['granted']} granted, {d['used']} used, {d['refused']} refused, {d['illegal']} illegal; radarcal: {mk['double_vulnerability']}")
    print(f"\nwall {time.perf_counter() - tic:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

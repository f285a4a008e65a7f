"""What radarcal's marks score against the referee simulator (issue #20): one command, printed tables.

    PYTHONPATH=$PWD python -m benchmarks.referee [DIR] [--seeds 2,3,5] [--frames 1350] [--season 2026]

Replays: `radarcal synth match` (seeds 2, 3, 5; 1350 frames = 45 s; 9 ground robots + aerial, people at the boundary,
visible-part boxes with jitter / misses / false positives / 3<->4 swaps, clouds fired point by point and delivered
late, T_cam_lidar off 0.3 deg / 2 cm, four-point PnP field pose), made in DIR (default a temp folder) when missing.
Each run is `radarcal run --replay R --serial PTY --speed 1` against :class:`radarcal.synth.referee_sim.RefereeSim`
(the referee scores what arrives when it arrives). ``--speed 0.5`` (default): the replay and the referee's match
clock both run at half speed, so that radarcal keeps up on this shared 2-core machine (each run's FPS and how late it
ended are printed; at ``--speed 1`` under the other helpers' load runs fell to 18-27 FPS and ended up to 29 s late,
and their stale marks measured the load, not the marking). The link's rates stay wall-clock, so a match second
carries twice the frames of a real one. Parts:

1. per enemy robot: correct-mark seconds and the fraction of the match it was vulnerable (2026 rule: progress +5/s
   correct, -10/s wrong or not sent, vulnerable at >= 100 - UNCERTAIN rates), for each marking configuration
   (--no-roster, --roster --no-guess, --roster --guess; before those flags exist: the current run only);
2. camera miss: on seed 2 the detector misses one enemy robot for 10 s (15-25 s) while the LiDAR sees it
   (`--camera-miss`): correct-mark seconds of that robot with and without guessing;
3. truly absent: the same robot is not on the field (`--absent`): its wrong-mark seconds / match seconds with and
   without guessing (goal < 1/3);
4. the link: frames over the byte budget / rate, malformed frames, and every season's 0x0305 layout decoded by the
   simulator (the sample replay, 3 s per season);
5. double vulnerability: `--dv-at 20` with chances granted at 10 s and 30 s: requests seen, used, refused, illegal.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEEDS = (2, 3, 5)
MISS = (15.0, 25.0)
# guessing fills empty roster slots, so it needs the roster (`--no-roster --guess` is `--no-roster`)
CONFIGS = (("no roster, no guess", ["--no-roster", "--no-guess"]), ("roster, no guess", ["--roster", "--no-guess"]), ("roster + guess", ["--roster", "--guess"]))


def _make(out: Path, seed: int, frames: int, extra: list[str] = ()) -> Path:
    from radarcal.cli.main import main as cli

    if not (out / "meta.json").is_file():
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli(["synth", "match", str(out), "--frames", str(frames), "--seed", str(seed), "--lidar-points", "6000", "--json", *extra])
        assert rc == 0, f"synth match {out} failed"
    return out


def _has_marking_flags() -> bool:
    import inspect

    from radarcal.cli import run_cmd

    return "roster" in inspect.signature(run_cmd.run).parameters


def _pick_robot(replay: Path, window: tuple[float, float], enemy: str = "blue") -> str:
    """The enemy ground robot the camera and the LiDAR both see most inside ``window`` (the one a camera miss hurts)."""
    count: dict[str, int] = {}
    for line in (replay / "truth.jsonl").read_text().splitlines():
        d = json.loads(line)
        if not window[0] <= d["t"] <= window[1]:
            continue
        for r in d["robots"]:
            if r["label"].startswith(enemy + "_") and r["label"] != f"{enemy}_6" and r["visible"] and r["lidar_hits"] > 0:
                count[r["label"]] = count.get(r["label"], 0) + 1
    return max(sorted(count), key=lambda k: count[k])


def _match(replay: Path, season: int, run_args: list[str], grants: tuple[float, ...] = (), speed: float = 1.0) -> tuple[dict, dict]:
    from radarcal.io.replay import open_replay_folder
    from radarcal.runtime.referee_season import rules
    from radarcal.synth.referee_serve import play_match
    from radarcal.synth.referee_sim import RefereeSim, Truth

    rep = open_replay_folder(replay)
    sim = RefereeSim(rules(season), Truth.from_lines(rep.truth_by_frame().values()), team=str(rep.meta.get("station", "red")), dv_grants=grants)
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cmd = [sys.executable, "-m", "radarcal", "run", "--replay", str(replay), "--season", str(season), "--speed", f"{speed:g}", "--quiet", "--json", *run_args]
    res, proc = play_match(sim, cmd, timeout_s=900, env=env, cwd=ROOT, speed=speed)
    if proc.returncode != 0:
        raise RuntimeError(f"radarcal run failed ({proc.returncode}): {proc.stderr[-1500:]}")
    return res.summary, json.loads(proc.stdout)


def _link_totals(summaries: list[dict]) -> dict:
    keys = ("frames", "layout_checked", "malformed_total", "over_rate", "over_link_budget", "over_interaction_budget")
    return {k: sum(s["link"].get(k, 0) for s in summaries) for k in keys}


def _row(s: dict, label: str) -> dict:
    return next(r for r in s["robots"] if r["robot"] == label)


def take_option(args: list[str], name: str, default: str) -> str:
    """``--name VALUE`` taken out of ``args`` (the benchmarks' own argv), or ``default``."""
    if name in args:
        i = args.index(name)
        v = args[i + 1]
        del args[i : i + 2]
        return v
    return default


def main(argv: list[str]) -> int:
    args = list(argv)

    def opt(name: str, default: str) -> str:
        return take_option(args, name, default)

    seeds = tuple(int(s) for s in opt("--seeds", ",".join(map(str, SEEDS))).split(","))
    frames = int(opt("--frames", "1350"))
    season = int(opt("--season", "2026"))
    speed = float(opt("--speed", "0.5"))
    work = Path(args[0]) if args else Path(tempfile.mkdtemp(prefix="radarcal_referee_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    flags = _has_marking_flags()
    configs = CONFIGS if flags else (("current run (no marking flags yet)", []),)
    t_start = time.perf_counter()
    print(f"replays in {work}; season {season}; replay and referee clock at {speed:g} x real time; {frames} frames ({frames / 30:.0f} s) per replay; seeds {seeds}; marking flags {'present' if flags else 'absent'}", flush=True)
    results: dict = {"season": season, "frames": frames, "seeds": list(seeds), "configs": [c for c, _ in configs], "runs": {}}
    all_summaries: list[dict] = []

    # 1. per robot, per configuration
    per: dict[tuple[int, str], dict] = {}
    for seed in seeds:
        rep = _make(work / f"seed{seed}", seed, frames)
        for name, extra in configs:
            s, run = _match(rep, season, extra, speed=speed)
            per[(seed, name)] = s
            all_summaries.append(s)
            results["runs"][f"seed{seed}/{name}"] = {"sim": s, "fps": run.get("fps"), "wall_s": run.get("wall_s"), "serial": run.get("serial")}
            lag = run.get("wall_s", 0.0) - frames / 30.0 / speed  # a paced run that cannot keep up ends late: its marks are stale
            print(f"  seed {seed} {name}: total correct {s['total']['correct_s']:.1f} s, score {s['total']['score']:.0f}; run {run.get('fps', 0):.1f} FPS, "
                  f"ended {lag:+.1f} s after the replay's length", flush=True)
    print(f"\n1. correct-mark seconds / % of the match vulnerable, per enemy robot (season {season}, {frames / 30:.0f} s matches)")
    head = f"{'seed':>4s} {'robot':7s} " + " ".join(f"{c:>22s}" for c, _ in configs)
    print(head)
    means = {c: [0.0, 0.0, 0] for c, _ in configs}
    for seed in seeds:
        robots = [r["robot"] for r in per[(seed, configs[0][0])]["robots"] if r["off_field_s"] < per[(seed, configs[0][0])]["match_s"] / 2]
        for lb in robots:
            cells = []
            for c, _ in configs:
                r = _row(per[(seed, c)], lb)
                v = r["vulnerable_frac"] or 0.0
                cells.append(f"{r['correct_s']:8.1f} s / {100 * v:5.1f} %")
                means[c][0] += r["correct_s"]
                means[c][1] += v
                means[c][2] += 1
            print(f"{seed:4d} {lb:7s} " + " ".join(f"{x:>22s}" for x in cells))
    print(f"{'mean':>4s} {'':7s} " + " ".join(f"{m[0] / max(m[2], 1):8.1f} s / {100 * m[1] / max(m[2], 1):5.1f} %".rjust(22) for m in means.values()))
    results["mean_per_robot"] = {c: {"correct_s": m[0] / max(m[2], 1), "vulnerable_frac": m[1] / max(m[2], 1)} for c, m in means.items()}

    # 2./3. camera miss and truly absent, guessing on / off
    seed = seeds[0]
    base = work / f"seed{seed}"
    robot = _pick_robot(base, MISS)
    miss = _make(work / f"seed{seed}_miss", seed, frames, ["--camera-miss", f"{robot}:{MISS[0]:g}:{MISS[1]:g}"])
    absent = _make(work / f"seed{seed}_absent", seed, frames, ["--absent", robot])
    pair = ((("no guess", ["--no-guess"]), ("guess", ["--guess"])) if flags else (("current run", []),))
    print(f"\n2./3. seed {seed}, {robot}: camera misses it {MISS[0]:g}-{MISS[1]:g} s (LiDAR sees it) / it is truly absent")
    print(f"{'':10s} {'miss: correct s':>16s} {'miss: wrong s':>14s} {'absent: wrong s':>16s} {'absent: wrong/match':>20s}")
    results["camera_miss"] = {"robot": robot, "window": MISS}
    for name, extra in pair:
        s_m, _ = _match(miss, season, extra, speed=speed)
        s_a, _ = _match(absent, season, extra, speed=speed)
        all_summaries += [s_m, s_a]
        rm, ra = _row(s_m, robot), _row(s_a, robot)
        frac = ra["wrong_s"] / max(s_a["match_s"], 1e-9)
        print(f"{name:10s} {rm['correct_s']:16.1f} {rm['wrong_s']:14.1f} {ra['wrong_s']:16.1f} {frac:20.3f}")
        results["camera_miss"][name] = {"miss_correct_s": rm["correct_s"], "miss_wrong_s": rm["wrong_s"], "absent_wrong_s": ra["wrong_s"], "absent_wrong_frac": frac}

    # 4. every season's layout through the simulator's decoder (sample replay, 3 s each)
    from radarcal.runtime.referee_season import KNOWN_SEASONS, rules

    print("\n4. link: every season's layout decoded by the simulator (sample replay, 90 frames)")
    print(f"{'season':>6s} {'layout':>9s} {'0x0305':>7s} {'checked':>8s} {'malformed':>9s} {'over rate':>9s} {'over budget':>11s} {'correct s':>9s}")
    results["seasons"] = {}
    for sn in KNOWN_SEASONS:
        s, _ = _match(ROOT / "datasets" / "sample_replay", sn, ["--max-frames", "90"])
        all_summaries.append(s)
        k = s["link"]
        over = k["over_link_budget"] + k["over_interaction_budget"]
        print(f"{sn:6d} {rules(sn).map_layout.value:>9s} {k['by_cmd'].get('0x0305', 0):7d} {k['layout_checked']:8d} {k['malformed_total']:9d} {k['over_rate']:9d} {over:11d} {s['total']['correct_s']:9.1f}")
        results["seasons"][sn] = k
    # 5. a double-vulnerability policy through the simulator's 0x0121 counter
    if flags:
        s, run = _match(base, season, ["--dv-at", "20"], grants=(10.0, 30.0), speed=speed)
        all_summaries.append(s)
        d = s["double_vulnerability"]
        results["double_vulnerability"] = d
        print(f"\n5. --dv-at 20 (chances at 10 s, 30 s): {d['granted']} granted, {d['used']} used, {d['refused']} refused, {d['illegal']} illegal; "
              f"events {d['events']}")
    tot = _link_totals(all_summaries)
    results["link_totals"] = tot
    print(f"\nall {len(all_summaries)} runs: {tot['frames']} frames from radarcal, {tot['layout_checked']} 0x0305 layouts checked, {tot['malformed_total']} malformed, "
          f"{tot['over_rate']} over rate, {tot['over_link_budget']} over the link budget, {tot['over_interaction_budget']} over the 0x0301 budget")  # fmt: skip
    print(f"wall {time.perf_counter() - t_start:.0f} s")
    (work / "referee_bench.json").write_text(json.dumps(results, indent=1, default=str))
    bad = tot["malformed_total"] + tot["over_link_budget"] + tot["over_interaction_budget"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""LiDAR drift monitor (``radarcal run --drift-check-s``): detection of a bumped LiDAR and false alarms.

    PYTHONPATH=$PWD python -m benchmarks.drift [--seeds 0,1,2] [--seconds 10]
    PYTHONPATH=$PWD python -m benchmarks.drift latency REPLAY [SPEED]   # frame latency, monitor off vs on

Clouds ray cast (``synth.field.simulate_lidar``, Mid-70-like rosette, 4 k points per 0.1 s, 2 cm range noise, ten
robots moving ~1.5 m/s) from a station behind either end, on both field families: the built-in polygon field and
HITSZ's real 2024 mesh (``docs/fields/hitsz_rmuc2024.field.yaml``; skipped when ../shared is absent). Per seed:
an unbumped stream (false alarms, largest measured drift), a stream bumped by 3 cm / 0.3 deg at t = 3 s (first
warning after the bump, measured drift vs the truth) and one bumped by 1 cm / 0.04 deg (below the threshold: must
not warn). Checks every 1 s on the last 1 s of clouds, inline (``threaded=False``), wall time per check printed.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIELD_YAML = ROOT / "docs" / "fields" / "hitsz_rmuc2024.field.yaml"
MESH = ROOT.parent / "shared" / "datasets" / "hitsz_rmuc_field_meshes" / "24_bg2align_fix1.stl"


def lidar_stream(fm, seed: int, bump_m: float, bump_deg: float, t_bump: float, seconds: float, points: int = 4000):
    """[(t, cloud (N,3) in the LiDAR frame)] at 10 Hz with ten robots moving; from ``t_bump`` on the LiDAR sits at a
    pose moved by exactly ``bump_deg`` / ``bump_m`` (random axis and direction). Returns (stream, T_field_lidar
    before, after)."""
    from radarcal import geometry
    from radarcal.synth.field import default_rig, make_robots, robot_states, scene_boxes, simulate_lidar

    rng = np.random.default_rng(seed)
    station = "red" if seed % 2 == 0 else "blue"
    rig = default_rig(fm, rng, station)
    robots = make_robots(fm, 10, rng, 1.5, station)
    T0 = rig.T_field_lidar
    T1 = geometry.perturb_T(T0, bump_deg, bump_m, rng) if bump_m or bump_deg else T0
    out = []
    for k in range(int(round(seconds * 10))):
        t = 0.1 * k
        p, yw = robot_states(fm, robots, np.array([t]))
        pts = simulate_lidar(fm, scene_boxes(fm, robots, p[0], yw[0]), T1 if t >= t_bump else T0, t, points, rng, 10 * points, 0.02)[0]
        out.append((t, pts))
    return out, T0, T1


def monitor_stream(fm, T_ref, stream, every: float = 1.0):
    """Feed ``stream`` through an inline :class:`DriftMonitor`; returns (monitor, warnings said)."""
    from radarcal.runtime.drift import DriftConfig, DriftMonitor

    said: list[str] = []
    mon = DriftMonitor(fm, T_ref, DriftConfig(check_every_s=every, window_s=every), "lidar0", threaded=False, on_warning=said.append)
    for t, pts in stream:
        mon.add_cloud(t, pts)
    return mon, said


def main(argv: list[str]) -> int:
    from radarcal import geometry
    from radarcal.field import builtin_field, load_field

    args = list(argv)
    if args and args[0] == "latency":
        latency(args[1], args[2] if len(args) > 2 else "1")
        return 0
    seeds, seconds = "0,1,2", 10.0
    if "--seeds" in args:
        seeds = args[args.index("--seeds") + 1]
    if "--seconds" in args:
        seconds = float(args[args.index("--seconds") + 1])
    fams = [("built-in rmuc_schematic", builtin_field("rmuc_schematic"))]
    if MESH.is_file():
        fams.append(("HITSZ 2024 mesh", load_field(FIELD_YAML)))
    else:
        print(f"(mesh family skipped: {MESH} absent)")
    print("| field | seed | unbumped: checks / false alarms / largest drift | bump 3 cm / 0.3 deg at t=3 s: warned after | measured vs truth | 1 cm / 0.04 deg: warned | s per check (median) |")
    print("|---|---|---|---|---|---|---|")
    for name, fm in fams:
        for seed in (int(s) for s in seeds.split(",")):
            st, T0, _ = lidar_stream(fm, 10 + seed, 0.0, 0.0, 1e9, seconds)
            mon, said = monitor_stream(fm, T0, st)
            ok = [c for c in mon.checks if np.isfinite(c.deg)]
            big_m, big_deg = max(c.m for c in ok), max(c.deg for c in ok)
            secs = [c.seconds for c in mon.checks]
            st, T0, T1 = lidar_stream(fm, seed, 0.03, 0.3, 3.05, 8.0)
            mb, said_b = monitor_stream(fm, T0, st)
            true_deg, true_m = geometry.pose_error(T1, T0)
            last = mb.checks[-1]
            after = f"{mb.first_warning_t - 3.05:.1f} s" if mb.first_warning_t is not None else "NOT warned"
            st, T0, _ = lidar_stream(fm, 20 + seed, 0.01, 0.04, 2.05, 6.0)
            ms, said_s = monitor_stream(fm, T0, st)
            print(f"| {name} | {seed} | {len(mon.checks)} / {len(said)} / {100 * big_m:.2f} cm {big_deg:.3f} deg | {after} | "
                  f"{100 * last.m:.2f} cm {last.deg:.3f} deg vs {100 * true_m:.2f} cm {true_deg:.3f} deg | {'YES' if said_s else 'no'} | "
                  f"{np.median(secs + [c.seconds for c in mb.checks]):.2f} |", flush=True)  # fmt: skip
    return 0



def latency(replay: str, speed: str = "1") -> None:
    """Frame latency of ``radarcal run --replay R`` with the drift monitor off and on (every 1 s), same process."""
    import contextlib
    import io
    import json

    from radarcal.cli.main import main as cli

    print("| `--drift-check-s` | frames | checks | per-frame ms median / p95 (cloud + localise + track) | largest drift | CPU s per check (median) |")
    print("|---|---|---|---|---|---|")
    for s in ("0", "1", "5", "0", "1", "5"):
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert cli(["run", "--replay", replay, "--drift-check-s", s, "--speed", speed, "-q", "--json"]) == 0
        d = json.loads(buf.getvalue())
        lat = d["latency_ms"]
        med = sum(lat[k]["median"] for k in ("cloud", "localise", "track"))
        p95 = sum(lat[k]["p95"] for k in ("cloud", "localise", "track"))
        dr = d.get("drift")
        big = f"{dr['max']['cm']:.2f} cm {dr['max']['deg']:.3f} deg" if dr and dr["max"] else "-"
        print(f"| {s} | {d['frames']} | {dr['checks'] if dr else '-'} | {med:.2f} / {p95:.2f} | {big} | {dr['median_check_cpu_s'] if dr else '-'} |", flush=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

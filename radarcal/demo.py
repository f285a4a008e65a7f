"""``make demo``: run ``radarcal run`` on the embedded sample replay and show what it did.

Uses ``datasets/sample_replay/`` (regenerated with ``datasets/make_sample.py`` when missing), writes
``demo_out/tracks.jsonl`` and ``demo_out/minimap.png``, and prints the accuracy against the replay's truth.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "datasets" / "sample_replay"
OUT = ROOT / "demo_out"


def main() -> int:
    from radarcal.cli.main import main as cli

    if not (SAMPLE / "meta.json").is_file():
        print(f"radarcal demo: {SAMPLE} missing, generating it with datasets/make_sample.py ...", flush=True)
        subprocess.run([sys.executable, str(ROOT / "datasets" / "make_sample.py")], check=True)
    OUT.mkdir(exist_ok=True)
    tracks, minimap, summary = OUT / "tracks.jsonl", OUT / "minimap.png", OUT / "summary.json"
    # the sample's robots are mostly blue: playing blue makes blue_7 our (tracked) sentry and blue_1 our hero
    argv = ["run", "--replay", str(SAMPLE), "--team", "blue", "--out", str(tracks), "--minimap", str(minimap), "--json"]
    print("radarcal demo: radarcal " + " ".join(argv), flush=True)
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = cli(argv)
    if code != 0:
        print(buf.getvalue())
        return code
    s = json.loads(buf.getvalue())
    summary.write_text(json.dumps(s, indent=2) + "\n")
    meta = json.loads((SAMPLE / "meta.json").read_text())
    acc = s["accuracy"]
    lat = s["latency_ms"]
    rf = s["robot_frames"]
    print(f"  replay: {meta['n_frames']} camera frames at {meta['fps']:g} fps, LiDAR {meta['lidar_hz']:g} Hz, field {meta['field']}, seed {meta['seed']}")
    print(f"  ran {s['frames']} frames in {s['wall_s']:.2f} s ({s['fps']:.0f} FPS with precomputed detections), {s['clouds']} clouds fused")
    print(f"  robot positions: {rf.get('lidar', 0)} from LiDAR clusters, {rf.get('depth', 0)} from LiDAR depth in a box, {rf.get('ground', 0)} from the ground ray, {rf.get('predicted', 0)} predicted by the tracker")
    print(f"  accuracy vs truth.jsonl: {acc['located']}/{acc['visible']} visible robots located, horizontal error median {acc['median_m']:.3f} m, "
          f"p95 {acc['p95_m']:.3f} m, max {acc['max_m']:.3f} m")
    print("  per-stage latency ms (median): " + ", ".join(f"{k} {v['median']:.2f}" for k, v in lat.items()))
    lines = [json.loads(ln) for ln in tracks.read_text().splitlines()]
    guided = [ln for ln in lines if (ln.get("sentry") or {}).get("target")]
    ranged = [ln for ln in lines if ln.get("hero_range_m") is not None]
    if guided:
        sg = guided[-1]["sentry"]
        print(f"  sentry guidance in {len(guided)} frames; e.g. t={guided[-1]['t']:.2f} s: nearest enemy {sg['target']} at "
              f"dx={sg['dx']:+.2f} m, dy={sg['dy']:+.2f} m ({sg['distance']:.2f} m) from our sentry")
    if ranged:
        print(f"  hero range in {len(ranged)} frames; last: hero -> enemy outpost {ranged[-1]['hero_range_m']:.2f} m (offset included)")
    print(f"  wrote {tracks} (one JSON line per frame), {minimap}, {summary}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

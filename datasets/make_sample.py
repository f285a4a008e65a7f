"""Regenerate ``datasets/sample_replay/`` (the replay ``make demo`` runs on) with ``radarcal synth field``.

    python datasets/make_sample.py            # rewrites datasets/sample_replay/ from its seed
    python datasets/make_sample.py --check    # regenerates into a temp folder and compares every byte

The generator is deterministic per seed. The one thing that is not is the provenance time stamp the bundle writer
puts into ``calib.yaml``; this script pins it to a fixed value so the folder is reproducible bit for bit.
Size: ~4 MB (150 frames = 5 s at 30 fps, 50 LiDAR clouds of 3000 points, images rendered at 0.25 scale).
"""

from __future__ import annotations

import contextlib
import filecmp
import io
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
NAME = "sample_replay"
ARGS = ["--frames", "300", "--seed", "7", "--robots", "6", "--lidar-points", "3000", "--image-every", "10", "--image-scale", "0.5", "--jpeg-quality", "60"]
PINNED_TIME = "2026-01-01T00:00:00+00:00"


def generate(parent: Path) -> Path:
    """Write ``parent/sample_replay`` (the command line recorded inside is the same wherever it is written)."""
    sys.path.insert(0, str(HERE.parent))
    from radarcal.cli.main import main as cli

    out = parent / NAME
    if out.exists():
        shutil.rmtree(out)
    cwd = os.getcwd()
    argv0 = sys.argv
    try:
        os.chdir(parent)
        sys.argv = ["radarcal", "synth", "field", NAME, *ARGS]  # provenance records this command line
        with contextlib.redirect_stdout(io.StringIO()):
            code = cli(["synth", "field", NAME, *ARGS])
    finally:
        os.chdir(cwd)
        sys.argv = argv0
    if code != 0:
        raise SystemExit(f"radarcal synth field failed with exit code {code}")
    calib = out / "calib.yaml"
    calib.write_text(re.sub(r"time: '[^']*'", f"time: '{PINNED_TIME}'", calib.read_text(encoding="utf-8")), encoding="utf-8")
    return out


def _same_json(a: Path, b: Path, rel_tol: float = 1e-12) -> bool:
    """JSON files equal up to the last bits of their floats: numpy / BLAS builds differ in rounding (landmark pixels
    came out 312.487389581453 vs ...45304 on a fresh install), which is not a different sample."""
    import json
    import math

    def same(x, y) -> bool:
        if isinstance(x, float) and isinstance(y, (int, float)) and not isinstance(y, bool):
            return math.isclose(x, y, rel_tol=rel_tol, abs_tol=1e-12)
        if type(x) is not type(y):
            return False
        if isinstance(x, dict):
            return x.keys() == y.keys() and all(same(x[k], y[k]) for k in x)
        if isinstance(x, list):
            return len(x) == len(y) and all(same(u, v) for u, v in zip(x, y))
        return x == y

    try:
        return same(json.loads(a.read_text(encoding="utf-8")), json.loads(b.read_text(encoding="utf-8")))
    except ValueError:
        return False


def same_tree(a: Path, b: Path) -> list[str]:
    """Files that differ between two generated trees: bytes, except JSON files, compared value by value."""
    diffs = []
    fa = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    fb = sorted(p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file())
    if fa != fb:
        diffs.append(f"file lists differ: {sorted(set(fa) ^ set(fb))[:5]}")
    for rel in set(fa) & set(fb):
        if filecmp.cmp(a / rel, b / rel, shallow=False):
            continue
        if not (rel.endswith(".json") and _same_json(a / rel, b / rel)):
            diffs.append(rel)
    return diffs


def main(argv: list[str]) -> int:
    if "--check" in argv:
        with tempfile.TemporaryDirectory() as tmp:
            fresh = generate(Path(tmp))
            diffs = same_tree(HERE / NAME, fresh)
        print("identical" if not diffs else f"DIFFERENT: {diffs[:10]}")
        return 0 if not diffs else 1
    out = generate(HERE)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"wrote {out} ({size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

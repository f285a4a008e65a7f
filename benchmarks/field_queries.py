"""Which backing answers the runtime's field queries fastest (per query, same process, same points).

Run: ``PYTHONPATH=$PWD python -m benchmarks field_queries`` (needs ../shared/datasets/hitsz_rmuc_field_meshes for the
mesh rows; the polygon rows always run).

Queries, as the runtime makes them per frame:
- static test ``contains`` of one Mid-70 cloud (20 k points): voxel grid gather | height raster band test
  (surface only) | open3d ``RaycastingScene.compute_distance`` < grow;
- ``surface_z`` of 20 track positions: polygons (even-odd) | height raster | open3d ray cast down;
- ground-ray ``intersect_rays`` of 20 box bottoms from a 2.5 m station: polygons (analytic) | raster march |
  open3d ``cast_rays``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from radarcal.field import load_field

MESH = Path(os.environ.get("RADARCAL_SHARED_DATASETS", Path(__file__).resolve().parents[1].parent / "shared" / "datasets")) / "hitsz_rmuc_field_meshes" / "24_bg2align_fix1.stl"


def _time(fn, reps: int) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t) / reps


def rows(fm, rng, reps: int = 20) -> list[tuple[str, str, float]]:
    import open3d as o3d

    out = []
    grid = fm.occupancy_grid(0.08, 0.3)
    raster = fm.height_raster()
    scene = fm.raycasting_scene()
    cloud = rng.uniform([0, 0, -0.1], [28, 15, 2.0], (20_000, 3))
    out.append(("contains 20k pts", "voxel grid gather", _time(lambda: grid.contains(cloud), reps)))
    out.append(("contains 20k pts", "height-raster band", _time(lambda: np.abs(cloud[:, 2] - raster.lookup(cloud[:, :2])) < 0.3, reps)))
    ct = o3d.core.Tensor(cloud.astype(np.float32))
    out.append(("contains 20k pts", "open3d compute_distance", _time(lambda: scene.compute_distance(ct).numpy() < 0.3, reps)))
    xy = rng.uniform([1, 1], [27, 14], (20, 2))
    if fm.mesh is None:
        out.append(("surface_z 20 xy", "polygons (even-odd)", _time(lambda: fm.surface_z(xy), reps)))
    out.append(("surface_z 20 xy", "height raster", _time(lambda: raster.lookup(xy), reps)))
    rays = o3d.core.Tensor(np.column_stack([xy, np.full(20, 10.0), np.zeros((20, 2)), -np.ones(20)]).astype(np.float32))
    out.append(("surface_z 20 xy", "open3d cast_rays", _time(lambda: scene.cast_rays(rays), reps)))
    o = np.tile([-0.6, 11.5, 2.5], (20, 1))
    tgt = np.column_stack([xy, np.zeros(20)])
    d = tgt - o
    if fm.mesh is None:
        out.append(("ground rays x20", "polygons (analytic)", _time(lambda: fm.ray_hits(o, d), reps)))
    else:
        out.append(("ground rays x20", "height-raster march", _time(lambda: fm.ray_hits(o, d), reps)))
    out.append(("ground rays x20", "raster march (polygon field)" if fm.mesh is None else "height-raster march", _time(lambda: raster.march(o, d), reps)))
    r2 = o3d.core.Tensor(np.hstack([o, d]).astype(np.float32))
    out.append(("ground rays x20", "open3d cast_rays", _time(lambda: scene.cast_rays(r2), reps)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=20)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    fields = [("rmuc2024 (polygons)", load_field("rmuc2024"))]
    if MESH.is_file():
        fields.append(("24_bg2align_fix1.stl (mesh)", load_field(MESH)))
    else:
        print(f"(mesh rows skipped: {MESH} not present)")
    print(f"{'field':28s} {'query':18s} {'backing':28s} {'µs/query':>10s}")
    seen = set()
    for name, fm in fields:
        for q, backing, t in rows(fm, rng, a.reps):
            if (name, q, backing) in seen:
                continue
            seen.add((name, q, backing))
            print(f"{name:28s} {q:18s} {backing:28s} {t * 1e6:10.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

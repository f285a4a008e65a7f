"""Where the range error of far robots comes from, per camera (issue #19): every box fix of a wide + tele run.

    RADARCAL_BENCH_CACHE=/tmp/mc/cache PYTHONPATH=$PWD python -m benchmarks.multicam_fixes A:1,2,3 B:11,12

The replays are those of :mod:`benchmarks.multicam` (same cache, same families). The two-camera run is instrumented
at ``Pipeline._locator``: every box a camera frame locates (box depth, else the ground ray) is recorded with its
:class:`~radarcal.runtime.fusion.BoxDepth`, and the ground ray of its bottom centre is computed beside it (also for
the boxes that have a depth). Each box is given to the truth robot, visible in that camera within 0.4 m of its
bearing, whose projected box covers most of it (a misread number is not its robot). Per camera and source, over
robots beyond 15 m of the wide camera: the error along the horizontal view (the range) and across it, the
standardised error ``|along| / sigma`` (is the fix's sigma honest?), boxes cut by the image's side edge apart; the
ground ray of the boxes with a depth (what fusing it would bring); and the same robot-frame's box depth in both
cameras (does the tele's tighter box give a better depth?).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.multicam import _cli, _selection, replay


def record_fixes(rep: Path, cameras: str = "cam0,cam1") -> list[dict]:
    """Run ``radarcal run`` on the replay and return every located box: camera, t, box (xyxy px), label, p (3,)
    field, sigma, source, BoxDepth (or None), ground-ray point (3,) (NaN: none; its bottom edge is not a foot)."""
    from radarcal.runtime import fusion
    from radarcal.runtime import pipeline as pl

    rec: list[dict] = []
    depths: list = []
    orig_locator, orig_depth, orig_view_boxes = pl.Pipeline._locator, fusion.CloudQueue.depths_in_boxes, pl.Pipeline._view_boxes
    labels_of: dict[int, list] = {}

    def view_boxes(self, dets):
        b, lab, sc = orig_view_boxes(self, dets)
        labels_of[id(b)] = lab
        return b, lab, sc

    def depths_in_boxes(self, *a, **k):
        bds = orig_depth(self, *a, **k)
        depths.append(bds)
        return bds

    def locator(self, view, t, boxes, fixes):
        f = orig_locator(self, view, t, boxes, fixes)
        labels = labels_of.get(id(boxes))

        def locate_boxes(idx):
            depths.clear()
            p, sig, src, beyond = f(idx)
            bds = depths[-1] if depths and len(depths[-1]) == len(idx) else [None] * len(idx)  # the last call: the boxes' own depths
            b = boxes[list(idx)]
            ground = view.localiser.from_ground(np.column_stack([(b[:, 0] + b[:, 2]) / 2, b[:, 3]]))
            ground[pl.no_ground_ray(b, boxes, self.cfg.ground_min_aspect)] = np.nan
            for n, j in enumerate(idx):
                rec.append({"camera": view.name, "t": float(t), "box": boxes[j].copy(), "label": labels[j] if labels else None, "p": p[n].copy(),
                            "sigma": float(sig[n]), "source": str(src[n]), "depth": bds[n], "ground": ground[n]})  # fmt: skip
            return p, sig, src, beyond

        return locate_boxes

    pl.Pipeline._locator, fusion.CloudQueue.depths_in_boxes, pl.Pipeline._view_boxes = locator, depths_in_boxes, view_boxes
    try:
        with tempfile.TemporaryDirectory() as tmp:
            _cli(["run", "--replay", str(rep), "--camera", cameras, "--out", str(Path(tmp) / "out.jsonl"), "--json", "-q"])
    finally:
        pl.Pipeline._locator, fusion.CloudQueue.depths_in_boxes, pl.Pipeline._view_boxes = orig_locator, orig_depth, orig_view_boxes
    return rec


def attribute(rep: Path, rec: list[dict], min_range_m: float = 15.0) -> list[dict]:
    """Each located box against its truth robot: along / across errors (m) of the fix and of its ground ray."""
    from radarcal.camera import Camera
    from radarcal.geometry import invert_T
    from radarcal.synth.field import box_corners

    truth = json.loads((rep / "truth.json").read_text())
    sizes = {r["label"]: r["size_lwh"] for r in truth["robots"]}
    lines: dict[str, list] = {}
    for x in (rep / "truth.jsonl").read_text().splitlines():
        if x.strip():
            d = json.loads(x)
            lines.setdefault(d["frame"].split("/")[0], []).append(d)
    times = {c: np.array([d["t"] for d in v]) for c, v in lines.items()}
    cams = {c: (Camera.from_dict(v["camera"]), np.asarray(v["T_field_cam"], float), tuple(v["size"])) for c, v in truth["cameras"].items()}
    wide_xy = cams["cam0"][1][:2, 3]
    out = []
    for r in rec:
        if r["source"] == "none" or not np.isfinite(r["p"][0]):
            continue
        cam, T_field_cam, size = cams[r["camera"]]
        f = int(np.argmin(np.abs(times[r["camera"]] - r["t"])))
        robots = lines[r["camera"]][f]["robots"]
        X = np.array([q["p_field"] for q in robots], float)
        eye = T_field_cam[:2, 3]
        d, pm = X[:, :2] - eye, r["p"][:2] - eye
        bearing = np.abs(np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - np.arctan2(pm[1], pm[0]))))) * np.linalg.norm(pm)
        cand = [k for k in np.flatnonzero(bearing < 0.4) if r["camera"] in robots[k].get("visible_in", [])]
        if not cand:
            continue
        box = r["box"]

        def covered(k):
            uv, _, _ = cam.project_from(invert_T(T_field_cam), box_corners(X[k], sizes[robots[k]["label"]], robots[k]["yaw"]))
            iw = max(0.0, min(uv[:, 0].max(), box[2]) - max(uv[:, 0].min(), box[0]))
            ih = max(0.0, min(uv[:, 1].max(), box[3]) - max(uv[:, 1].min(), box[1]))
            return iw * ih / ((box[2] - box[0]) * (box[3] - box[1]))

        k = max(cand, key=covered)
        rng = float(np.linalg.norm(X[k, :2] - wide_xy))
        if rng < min_range_m:
            continue
        u = d[k] / np.linalg.norm(d[k])
        e = r["p"][:2] - X[k, :2]
        g = r["ground"][:2] - X[k, :2]
        out.append({"camera": r["camera"], "source": r["source"], "label": robots[k]["label"], "frame": f, "h": float(box[3] - box[1]),
                    "cut": bool(box[0] <= 1.0 or box[2] >= size[0] - 2.0), "along": float(e @ u), "across": float(e @ [-u[1], u[0]]),
                    "sigma": r["sigma"], "ground_along": float(g @ u) if np.isfinite(g[0]) else np.nan,
                    "points": r["depth"].n_box if r["depth"] is not None else 0})  # fmt: skip
    return out


def _q(a, q):
    return float(np.percentile(np.abs(a), q)) if len(a) else float("nan")


def report(rows: list[dict], title: str) -> None:
    print(f"== {title}: box fixes of robots beyond 15 m of the wide camera (m; along = range error)")
    print(f"{'camera':>6} {'source':>6} {'n':>5} {'h px':>5} {'pts':>4} | {'along med':>9} {'|along| p50':>11} {'p95':>5} {'> 0.4 m':>7} | {'|across| p95':>12} "
          f"{'cut by edge: n':>14} {'|across| p95':>12} | {'|along|/sigma p95':>17} | {'its ground ray |along| p50':>26} {'p95':>5}")  # fmt: skip
    for cam in sorted({r["camera"] for r in rows}):
        for src in ("depth", "ground"):
            R = [r for r in rows if r["camera"] == cam and r["source"] == src]
            if not R:
                continue
            a, c, s = (np.array([r[k] for r in R]) for k in ("along", "across", "sigma"))
            cut = np.array([r["cut"] for r in R])
            g = np.array([r["ground_along"] for r in R])
            g = g[np.isfinite(g)]
            print(f"{cam:>6} {src:>6} {len(R):5d} {np.median([r['h'] for r in R]):5.0f} {np.median([r['points'] for r in R]):4.0f} | {np.median(a):+9.3f} {_q(a, 50):11.3f} "
                  f"{_q(a, 95):5.2f} {100 * np.mean(np.abs(a) > 0.4):6.1f}% | {_q(c[~cut], 95):12.3f} {cut.sum():14d} {_q(c[cut], 95):12.3f} | {_q(a / s, 95):17.1f} | "
                  f"{_q(g, 50):26.3f} {_q(g, 95):5.2f}")  # fmt: skip
    pairs: dict[tuple, dict] = {}
    for r in rows:
        if r["source"] == "depth":
            pairs.setdefault((r["label"], r["frame"]), {})[r["camera"]] = r
    P = np.array([(v["cam0"]["along"], v["cam1"]["along"]) for v in pairs.values() if len(v) == 2]).reshape(-1, 2)
    if len(P):
        print(f"same robot-frame, box depth in both cameras ({len(P)}): |along| p50 wide {_q(P[:, 0], 50):.3f} tele {_q(P[:, 1], 50):.3f}, p95 wide {_q(P[:, 0], 95):.3f} "
              f"tele {_q(P[:, 1], 95):.3f}; over 0.4 m: wide {100 * np.mean(np.abs(P[:, 0]) > 0.4):.1f} %, tele {100 * np.mean(np.abs(P[:, 1]) > 0.4):.1f} %, "
              f"both {100 * np.mean((np.abs(P) > 0.4).all(axis=1)):.1f} %")  # fmt: skip


def main(argv: list[str]) -> int:
    cache = Path(os.environ.get("RADARCAL_BENCH_CACHE") or tempfile.mkdtemp(prefix="radarcal_multicam_"))
    cache.mkdir(parents=True, exist_ok=True)
    for fam, seeds in _selection(argv):
        rows = []
        for seed in seeds:
            rep = replay(cache, fam, seed)
            rows += attribute(rep, record_fixes(rep))
            print(f"  {fam} seed {seed} done", file=sys.stderr, flush=True)
        report(rows, f"family {fam}, seeds {', '.join(map(str, seeds))}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Why LiDAR-only localisation misses robots (issue #15): a breakdown of the missed robot-frames of a replay.

    PYTHONPATH=$PWD python -m benchmarks.lidar_misses DIR [DIR ...]   # `radarcal synth match` replays
    PYTHONPATH=$PWD python -m benchmarks.lidar_misses                 # seeds 1, 2, 3 made in a temporary folder

Runs ``radarcal run --no-camera`` (the pipeline in LiDAR-only mode) over each replay and, for every camera frame and
every robot the LiDAR sees (>= 3 returns in the newest cloud, the scorer's rule), with no output track within 0.3 m,
names the first stage that lost it, from the newest cloud:

* which returns are the robot's: the replay's intensity marks robot returns (60 +- 3, the rest 25 or 90; the
  runtime never reads it) and the nearest true robot at each point's firing time owns them;
* the static filter (crop, field model) or the learnt background removed them (fewer than 3 left);
* the cluster gates rejected the component holding most of them (which gate: :data:`REJECT_REASONS`);
* their cluster is mostly another robot's or clutter's points (merged);
* the track that took the cluster is tentative, a static suspect not reported yet, or was dropped;
* the track is output but > 0.3 m off: its cluster centre was > 0.3 m off (by range), or the centre was within
  0.3 m and the track is off (filter lag, prediction to the frame time).

Prints one table per replay and the sum, and the cluster-centre error (along / across the view) by range.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from radarcal.runtime.clusters import REJECT_REASONS

ROWS: list = []  # (replay, t, label, range, LiDAR hits, cause) of every miss, for a closer look
ROBOT_INTENSITY = (45.0, 75.0)  # radarcal.synth.detections: robot returns 60 +- 3, field 25, structures 90


class _Recorder:
    """Stands in for ``LidarFirst.filter`` and ``Tracker3D.update_clusters``: remembers what the newest cloud gave."""

    def __init__(self, lf):
        self.lf, self.flt, self.upd, self.upd_sparse = lf, lf.filter, lf.tracker.update_clusters, lf.tracker.update_sparse
        lf.filter, lf.tracker.update_clusters, lf.tracker.update_sparse = self, self._update_clusters, self._update_sparse
        self.last: dict = {}

    def __call__(self, pts, t):
        p, idx, bg = self.flt(pts, t)
        self.last = {"idx": idx, "bg": bg, "ids": [], "sparse_ids": []}
        return p, idx, bg

    def __getattr__(self, name):
        return getattr(self.flt, name)

    def _update_sparse(self, *a, **k):
        ids = self.upd_sparse(*a, **k)
        self.last["sparse_ids"] = list(ids)
        return ids

    def _update_clusters(self, *a, **k):
        ids = self.upd(*a, **k)
        self.last["ids"] = list(ids)
        return ids


def _truth(rep: Path):
    lines = [json.loads(s) for s in (rep / "truth.jsonl").read_text().splitlines() if s.strip()]
    labels = json.loads((rep / "truth.json").read_text())["labels"]
    t = np.array([d["t"] for d in lines])
    P = np.full((len(lines), len(labels), 3), np.nan)
    for f, d in enumerate(lines):
        for r in d["robots"]:
            P[f, labels.index(r["label"])] = r["p_field"]
    return lines, labels, t, P


def _at(t_truth: np.ndarray, P: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(len(t), R, 2) true robot positions interpolated to times ``t``."""
    out = np.empty((len(t), P.shape[1], 2))
    for r in range(P.shape[1]):
        for i in range(2):
            out[:, r, i] = np.interp(t, t_truth, P[:, r, i])
    return out


def breakdown(rep: Path) -> tuple[Counter, int, list]:
    """(miss counts by cause, LiDAR-seen robot-frames, [(range, along error, across error)] of kept robot clusters)."""
    from radarcal.bundle import load_bundle
    from radarcal.runtime.lidar_first import point_times
    from radarcal.runtime.loop import Pipeline, RunConfig
    from radarcal.runtime.sources import merge_by_time, open_replay

    r = open_replay(rep)
    b = load_bundle(r.bundle)
    meta = json.loads((rep / "meta.json").read_text())
    sweep, lat = float(meta.get("cloud_sweep_s", 0.1)), float(meta.get("cloud_latency_s", 0.0))
    pipe = Pipeline(b, meta["camera"], meta["lidar"], RunConfig.from_bundle(b, localise="lidar", cloud_sweep_s=sweep, cloud_latency_s=lat))
    lf = pipe.lidar_first
    rec = _Recorder(lf)
    truth_json = json.loads((rep / "truth.json").read_text())
    T_true = np.asarray(truth_json["T_field_cam0"], float) @ np.asarray(truth_json["T_cam0_lidar0"], float)
    lines, labels, t_truth, P = _truth(rep)
    by_frame = {d["frame"]: d for d in lines}
    causes: Counter = Counter()
    seen = 0
    centre_err: list = []
    cloud: dict = {}
    for frame, clouds in merge_by_time(r.camera_frames(), r.cloud_frames()):
        for c in clouds:
            pts = np.asarray(c.points, np.float32)
            pipe.add_cloud(c.t, pts)
            tp = point_times(len(pts), float(c.t), sweep, lat)
            pf = pts.astype(float) @ T_true[:3, :3].T + T_true[:3, 3]
            robot = (c.intensity >= ROBOT_INTENSITY[0]) & (c.intensity <= ROBOT_INTENSITY[1]) if c.intensity is not None else np.zeros(len(pts), bool)
            owner = np.full(len(pts), -1)
            if robot.any():
                at = _at(t_truth, P, tp[robot])
                d = np.linalg.norm(at - pf[robot, None, :2], axis=2)
                k = np.argmin(d, axis=1)
                owner[np.flatnonzero(robot)] = np.where(d[np.arange(len(k)), k] < 1.2, k, -1)
            cl = lf.last_clusters
            idx, bg = rec.last["idx"], rec.last["bg"]
            dyn_owner = owner[idx[~bg]]
            cloud = {"owner": owner, "field": np.bincount(owner[idx][owner[idx] >= 0], minlength=len(labels)),
                     "dyn": np.bincount(dyn_owner[dyn_owner >= 0], minlength=len(labels)), "dyn_owner": dyn_owner, "cl": cl,
                     "ids": rec.last["ids"], "sparse_ids": rec.last["sparse_ids"], "all": np.bincount(owner[owner >= 0], minlength=len(labels))}  # fmt: skip
            for k in range(len(cl)):  # centre error of clusters that are mostly one robot's
                own = dyn_owner[cl.labels == k]
                if len(own) and (own >= 0).mean() > 0.7:
                    rr = np.bincount(own[own >= 0]).argmax()
                    truth_xy = _at(t_truth, P, np.array([cl.t[k]]))[0, rr]
                    v = cl.centre[k, :2] - lf.sensor_xy
                    v /= np.linalg.norm(v)
                    e = cl.centre[k, :2] - truth_xy
                    centre_err.append((float(cl.range_m[k]), float(e @ v), float(e @ np.r_[-v[1], v[0]]), bool(cl.aerial[k])))
        res = pipe.process(frame.t, frame.name, [])
        tr_line = by_frame.get(frame.name)
        if tr_line is None or not cloud:
            continue
        O = np.array([ro.p_field[:2] for ro in res.robots]).reshape(-1, 2)
        for rob in tr_line["robots"]:
            if rob.get("lidar_hits", 0) < 3:
                continue
            seen += 1
            xy = np.asarray(rob["p_field"][:2])
            if len(O) and np.linalg.norm(O - xy, axis=1).min() <= 0.3:
                continue
            cause = _cause(labels.index(rob["label"]), xy, cloud, lf, t_truth, P)
            causes[cause] += 1
            ROWS.append((rep.name, round(frame.t, 3), rob["label"], round(float(np.hypot(*(xy - lf.sensor_xy))), 1), rob["lidar_hits"], cause))
    return causes, seen, centre_err


def _cause(ri: int, xy: np.ndarray, c: dict, lf, t_truth, P) -> str:
    """The first stage that lost robot ``ri`` (true position ``xy``) in the newest cloud ``c``."""
    if c["all"][ri] < 3:
        return "returns not attributed (< 3 robot returns near it)"
    if c["field"][ri] < 3:
        return "removed by the static filter (crop / field model)"
    if c["dyn"][ri] < 3:
        return "removed as learnt background"
    cl, own = c["cl"], c["dyn_owner"]
    mine = own == ri
    kept = cl.labels[mine]
    if not (kept >= 0).any():
        comp = np.bincount(cl.component[mine]).argmax()
        why = REJECT_REASONS[int(cl.rejected[comp])]
        sp = cl.sparse.labels[mine] if cl.sparse is not None else np.zeros(0, int)
        if (sp >= 0).any():  # sparse: a track could have taken it
            j = int(np.bincount(sp[sp >= 0]).argmax())
            if j < len(c["sparse_ids"]) and c["sparse_ids"][j] >= 0:
                return f"sparse ({why}), taken by a track, still > 0.3 m off"
            near = [o for o in lf.tracker.tracks if o.state != "tentative" and np.linalg.norm(o.x[:2] - xy) < 2.0]
            why += ", sparse; " + ("a track within 2 m did not take it" if near else "no track near")
        return f"cluster rejected: {why}"
    k = int(np.bincount(kept[kept >= 0]).argmax())
    members = own[cl.labels == k]
    if (members == ri).mean() < 0.6:
        other = members[members != ri]
        return "merged with another robot" if (other >= 0).sum() >= (other < 0).sum() else "merged with clutter"
    tid = c["ids"][k] if k < len(c["ids"]) else -1
    tr = next((o for o in lf.tracker.tracks if o.id == tid), None)
    rng = float(cl.range_m[k])
    band = "< 10 m" if rng < 10 else ("10-20 m" if rng < 20 else ">= 20 m")
    if tr is None:
        return "its track was dropped"
    if tr.state == "tentative":
        return "track tentative (not confirmed yet)"
    if not tr.evidence:
        return "static suspect (not reported until it moves)"
    truth_xy = _at(t_truth, P, np.array([cl.t[k]]))[0, ri]
    e = float(np.linalg.norm(cl.centre[k, :2] - truth_xy))
    if e > 0.3:
        return f"cluster centre > 0.3 m off ({band}{', aerial' if cl.aerial[k] else ''})"
    return "centre within 0.3 m, track output > 0.3 m off"


def main(argv: list[str]) -> int:
    if not argv:  # `python -m benchmarks`: the tuning seeds 1, 2, 3 (450 frames), made in a temporary folder
        import tempfile

        from benchmarks.lidar_first import _make

        base = Path(tempfile.mkdtemp(prefix="lf_miss_"))
        argv = [str(_make(base / f"m{s}", s)) for s in (1, 2, 3)]
    total: Counter = Counter()
    seen_all, errs = 0, []
    for d in argv:
        causes, seen, ce = breakdown(Path(d))
        total.update(causes)
        seen_all += seen
        errs += ce
        _print(Path(d).name, causes, seen)
    if len(argv) > 1:
        _print("all", total, seen_all)
    e = np.array([x[:3] for x in errs if not x[3]]).reshape(-1, 3)
    if not len(e):
        return 0
    print("\nground-robot cluster centres (mostly one robot's points): error along / across the view (m)")
    print("| range | clusters | along median | along p90 abs | across median abs | within 0.3 m |")
    print("|---|---|---|---|---|---|")
    for lo, hi in ((0, 10), (10, 15), (15, 20), (20, 25), (25, 40)):
        m = (e[:, 0] >= lo) & (e[:, 0] < hi)
        if m.any():
            w = np.hypot(e[m, 1], e[m, 2]) <= 0.3
            print(f"| {lo}-{hi} m | {m.sum()} | {np.median(e[m, 1]):+.3f} | {np.percentile(np.abs(e[m, 1]), 90):.3f} | {np.median(np.abs(e[m, 2])):.3f} | {100 * w.mean():.1f} % |")
    return 0


def _print(name: str, causes: Counter, seen: int) -> None:
    miss = sum(causes.values())
    print(f"\n{name}: {seen} LiDAR-seen robot-frames, {miss} without a track within 0.3 m ({100 * (1 - miss / max(seen, 1)):.1f} % within)")
    print("| cause | robot-frames | % of LiDAR-seen |")
    print("|---|---|---|")
    for k, v in causes.most_common():
        print(f"| {k} | {v} | {100 * v / max(seen, 1):.1f} % |")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""LiDAR-first localisation: robots found in the cloud, identities from the camera (issue #15).

Per cloud (:meth:`LidarFirst.add_cloud`): each point gets its firing time (the cloud's sweep and delivery latency
are modelled: points in firing order, ``t_i = t_arrival - latency - sweep + sweep (i + 0.5) / N``); the static
filter (:mod:`radarcal.runtime.background`) keeps the dynamic points, which join a short window of the last
``window_sweeps`` sweeps; older points that lie on a track are moved along its velocity to the newest time (so
integration does not smear moving robots); the window is clustered (:mod:`radarcal.runtime.clusters`) and the
clusters update the 3D tracks (:class:`radarcal.runtime.tracks.Tracker3D`) at their own mean point time.

Per camera frame (:meth:`LidarFirst.frame`): tracks' hulls projected into the image and matched with the boxes
(:mod:`radarcal.runtime.identity`), label votes, labels given out; boxes with no track take the box path (box depth
from the cloud queue, else the ground ray) as box-only fixes, which alone confirm a track only after several
consistent frames; tracks are predicted to the frame time and returned.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from radarcal.geometry import invert_T
from radarcal.runtime.background import FieldOccupancy, StaticFilter, VoxelBackground, field_occupancy, range_sigma
from radarcal.runtime.clusters import ClusterParams, cluster_points
from radarcal.runtime.identity import add_votes, assign_labels, decay_boxed_elsewhere, match_boxes, project_tracks, visible_parts
from radarcal.runtime.tracks import CONFIRMED, LOST, TENTATIVE, Track3D, Tracker3D  # noqa: F401

__all__ = ["LidarFirstConfig", "LidarFirst", "point_times", "fuse_fixes", "box_fix_order", "misread_holder", "on_other_robot", "LEGIBLE_PX"]

LIDAR_NOW_S = 0.3  # a track whose last LiDAR cluster is younger than this is seen by the LiDAR now
LEGIBLE_PX = 64.0  # box height (px) from which a robot's armour number (~1/4 of it) counts as fully legible


@dataclass
class LidarFirstConfig:
    window_sweeps: int = 1  # clouds integrated (measured trade-off in docs/runtime.md: 1 is best here)
    sweep_s: float = 0.1  # firing duration of one cloud (0: every point at the cloud time)
    latency_s: float = 0.0  # sweep end -> cloud time stamp
    learn_background: bool = True
    bg_voxel_m: float = 0.2
    bg_hits: float = 4.0  # decayed cloud count that makes a voxel background
    elsewhere_decay: float = 0.8  # identity.decay_boxed_elsewhere per tick (1: off); chosen on synth match seed 1
    bg_tau_s: float = 20.0
    crop_inset_m: float = 0.05
    sigma_rot_deg: float = 0.25  # calibration sigma the tolerances follow (bundle sigma when it has one)
    sigma_trans_m: float = 0.03
    # floor (m) of the ground fit's rms residual in the static filter's height tolerance (StaticFilter.min_rms_m),
    # with box fixes / LiDAR only: the measured ~9 mm lets far robots' lowest returns through LiDAR only; with a
    # camera it cost auto 0.4 points on seeds 1 and 2 (measured: docs/runtime.md), so auto keeps the old fixed 3 cm
    ground_rms_floor_m: tuple[float, float] = (0.03, 0.01)
    # wall margins the static filter offers (FieldOccupancy.margins_m), with box fixes / LiDAR only (None: the 8 cm
    # cell grid): on the cell grid auto lost on the sample replay (p95 0.305 -> 0.325 m; measured: docs/runtime.md)
    wall_margins_m: tuple = (FieldOccupancy.COARSE_MARGINS_M, None)
    compensate: bool = False  # move older window points along their track (measured worse: docs)
    seen_lidar_s: float = 0.25  # a track counts as seen by the LiDAR this long after its last cluster
    seen_box_s: float = 0.1
    box_shadow: bool = False  # run the box path beside; labels no LiDAR track holds now come from it (opt-in: docs)
    prefer_box_m: float = 0.3  # a LiDAR-seen track's box-depth fix farther than this from it is output instead
    sparse_clusters: bool = True  # tracks take components too sparse to start one (Tracker3D.update_sparse; measured: docs)
    suspect_protect_s: float = 5.0  # static suspects are not learnt as background during the run's first seconds
    sparse_sigma_m: float = 0.12  # added to a sparse ground component's sigma (its few returns: across the view)
    # added to the aerial robot's centre sigma, kept cluster or sparse: a few returns of a 0.8 m robot put it off
    # across the view (median |across| 0.24-0.27 m at 10-25 m; measured: docs/runtime.md)
    aerial_sigma_m: float = 0.25
    exclusion_m: float = 0.6  # output tracks nearer than this are one robot (a robot is <= 0.6 m across): one is measured
    lidar_only: bool = False  # no box fixes (LiDAR only, `--localise lidar`): only clusters measure the tracks
    # Tracker3D white acceleration (m/s^2) with box fixes (auto); with a camera a lower density made the sample
    # replay worse (measured: docs/runtime.md)
    accel_sigma: float = 3.0
    # clusters only (LiDAR only, `--localise lidar`): an interacting multiple model of two densities, so far centres'
    # 0.1-0.2 m jitter stays out of a cruising robot's velocity and a hard manoeuvre still moves the weight to the high
    # one (was one density of 1.5 m/s^2; measured: docs/runtime.md)
    lidar_only_accel: tuple[float, float] = (0.5, 2.0)
    imm_sojourn_s: float = 6.0

    def tracker(self) -> Tracker3D:
        """The 3D tracker this configuration runs: box fixes and clusters (one density), or clusters only (IMM)."""
        if self.lidar_only:
            return Tracker3D(imm_accel=self.lidar_only_accel, imm_sojourn_s=self.imm_sojourn_s)
        return Tracker3D(accel_sigma=self.accel_sigma)


def point_times(n: int, t_cloud: float, sweep_s: float, latency_s: float) -> np.ndarray:
    """Firing time of each of ``n`` points delivered in firing order at ``t_cloud``."""
    t_end = t_cloud - latency_s
    if sweep_s <= 0 or n == 0:
        return np.full(n, t_end)
    return t_end - sweep_s + sweep_s * (np.arange(n) + 0.5) / n


class LidarFirst:
    def __init__(self, T_field_lidar: np.ndarray, field_model, cfg: LidarFirstConfig | None = None, params: ClusterParams | None = None,
                 tracker: Tracker3D | None = None, camera=None, T_field_cam: np.ndarray | None = None):  # fmt: skip
        self.cfg = cfg or LidarFirstConfig()
        self.params = params or ClusterParams()
        self.T_field_lidar = np.asarray(T_field_lidar, float)
        self.sensor_xy = self.T_field_lidar[:2, 3].copy()
        L, W = field_model.size if field_model is not None else (28.0, 15.0)
        inset = self.cfg.crop_inset_m
        occ = field_occupancy(field_model, (-1.0, -1.0, L + 1.0, W + 1.0), margins_m=self.cfg.wall_margins_m[int(self.cfg.lidar_only)])
        bg = VoxelBackground((0.0, 0.0, -0.5, L, W, 3.5), self.cfg.bg_voxel_m, self.cfg.bg_tau_s, self.cfg.bg_hits) if self.cfg.learn_background else None
        self.filter = StaticFilter(self.T_field_lidar, occ, bg, (inset, inset, L - inset, W - inset),
                                   sigma_rot_rad=np.deg2rad(self.cfg.sigma_rot_deg), sigma_trans_m=self.cfg.sigma_trans_m,
                                   min_rms_m=self.cfg.ground_rms_floor_m[int(self.cfg.lidar_only)])  # fmt: skip
        self.tracker = tracker or self.cfg.tracker()
        # without box fixes a far robot seen only by a few returns gets a track from them (with box fixes its box
        # does: sparse-born tracks there took box-only fixes and labels of other robots, measured: docs/runtime.md)
        self.tracker.sparse_births = self.cfg.lidar_only
        self.tracker.same_robot_m = self.cfg.exclusion_m
        self.window: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=max(1, self.cfg.window_sweeps))
        self.camera = camera
        self.T_cam_field = invert_T(T_field_cam) if T_field_cam is not None else None
        self.pad_px = 3.0 + (camera.fx * np.deg2rad(self.cfg.sigma_rot_deg) if camera is not None else 0.0)
        self.protect_boxes: np.ndarray | None = None  # current detection boxes: their points are not learnt
        self.last_clusters = None
        self.fuse_box_depth = True
        from radarcal.runtime.tracks import TrackManager

        self.shadow = TrackManager() if self.cfg.box_shadow and camera is not None else None
        self.shadow_boxes: dict[str, int] = {}
        self.shadow_t = -np.inf
        self._proxy_ids: dict[str, int] = {}
        self._shadow_ok: set[str] = set()
        self.clouds = 0

    # --- clouds ----------------------------------------------------------------------------------------------------
    def add_cloud(self, t: float, points_lidar: np.ndarray) -> None:
        pts = np.asarray(points_lidar, np.float32).reshape(-1, 3)
        tp = point_times(len(pts), float(t), self.cfg.sweep_s, self.cfg.latency_s)
        t_ref = float(tp[-1]) if len(tp) else float(t)
        p, idx, bg = self.filter(pts, t_ref)
        # learn: every off-field point except those on tracked robots and inside detection boxes
        # (tracks a box has named or that have moved: a static unnamed cluster is what the background must learn)
        # (and, in the first ``suspect_protect_s``, the static suspects: a robot that moves off slowly is not eaten first)
        early = self.tracker.t0 is not None and t_ref - self.tracker.t0 < self.cfg.suspect_protect_s
        prot_xy = np.array([tr.x[:2] + tr.x[2:] * (t_ref - tr.t) for tr in self.tracker.tracks
                            if tr.state != TENTATIVE and (tr.evidence or (early and tr.static_suspect))]).reshape(-1, 2)  # fmt: skip
        learn = p
        if self.protect_boxes is not None and len(self.protect_boxes) and self.camera is not None and len(p):
            uv, ok, _ = self.camera.project_from(self.T_cam_field, p.astype(float))
            b = self.protect_boxes
            inb = ((uv[:, None, 0] >= b[None, :, 0]) & (uv[:, None, 0] <= b[None, :, 2]) & (uv[:, None, 1] >= b[None, :, 1]) & (uv[:, None, 1] <= b[None, :, 3])).any(1)
            learn = p[~(inb & ok)]
        self.filter.learn(learn, t_ref, prot_xy)
        dyn, tdyn = p[~bg], tp[idx[~bg]]
        self.window.append((dyn, tdyn))
        self._cluster(t_ref)
        self.clouds += 1

    def _cluster(self, t_ref: float) -> None:
        P = np.vstack([w[0] for w in self.window]).astype(float) if self.window else np.zeros((0, 3))
        Tm = np.concatenate([w[1] for w in self.window]) if self.window else np.zeros(0)
        if self.cfg.compensate and len(P) and self.tracker.tracks:
            old = Tm < t_ref - 0.5 * max(self.cfg.sweep_s, 0.05)
            if old.any():
                X = np.array([tr.x for tr in self.tracker.tracks])
                t0 = np.array([tr.t for tr in self.tracker.tracks])
                po, to = P[old], Tm[old]
                at = X[None, :, :2] + X[None, :, 2:] * (to[:, None, None] - t0[None, :, None])  # (M,T,2) track at each point's time
                d2 = ((po[:, None, :2] - at) ** 2).sum(-1)
                k = np.argmin(d2, axis=1)
                near = d2[np.arange(len(po)), k] < 0.6**2
                shift = X[k, 2:] * (t_ref - to)[:, None]
                po[near, :2] += shift[near]
                to = np.where(near, t_ref, to)
                P[old], Tm[old] = po, to
        surf = self.filter.occupancy.surface_at(P) if len(P) else np.zeros(0)
        cl = cluster_points(P, Tm, surf, self.sensor_xy, self.params)
        self.last_clusters = cl
        if len(cl):
            sigma = self._centre_sigma(cl, 0.0)
            ext = cl.hi - cl.lo
            hulls = [(cl.lo[j].copy(), cl.hi[j].copy()) for j in range(len(cl))]
            ids = self.tracker.update_clusters(cl.centre, sigma, cl.t, cl.aerial, ext, hulls, t_ref)
        else:
            ids = []
        sp = cl.sparse
        if self.cfg.sparse_clusters and sp is not None and len(sp):
            # a few returns from one rosette pass: the centre across the view is uncertain by up to half a robot
            self.tracker.update_sparse(sp.centre, self._centre_sigma(sp, self.cfg.sparse_sigma_m), sp.t, sp.aerial, set(ids))

    def _centre_sigma(self, cl, extra_ground_m: float) -> np.ndarray:
        """(K,) sigma (m) of cluster centres: 5 cm, the calibration at their range, 0.15 m / sqrt(points), and
        ``extra_ground_m`` for a ground robot or :attr:`LidarFirstConfig.aerial_sigma_m` for the aerial one."""
        s = range_sigma(cl.range_m, np.deg2rad(self.cfg.sigma_rot_deg), self.cfg.sigma_trans_m)
        return np.sqrt(0.05**2 + s**2 + (0.15 / np.sqrt(cl.n)) ** 2 + np.where(cl.aerial, self.cfg.aerial_sigma_m, extra_ground_m) ** 2)

    # --- camera frames ---------------------------------------------------------------------------------------------
    def track_hulls(self, t: float) -> tuple[list[Track3D], np.ndarray, np.ndarray]:
        """Tracks with a recent cluster and their field boxes (lo, hi) moved to time ``t``, at least robot-sized
        across and reaching down to the track's surface height."""
        trs = [tr for tr in self.tracker.tracks if tr.hull is not None and t - tr.t_lidar <= 0.6]
        if not trs:
            return trs, np.zeros((0, 3)), np.zeros((0, 3))
        dt = np.array([t - tr.t_points for tr in trs])
        shift = np.array([tr.x[2:] for tr in trs]) * dt[:, None]
        a = np.array([tr.hull[0] for tr in trs], float)
        b = np.array([tr.hull[1] for tr in trs], float)
        a[:, :2] += shift
        b[:, :2] += shift
        c = 0.5 * (a[:, :2] + b[:, :2])
        half = np.maximum(0.5 * (b[:, :2] - a[:, :2]), 0.22)
        za = np.where([tr.aerial for tr in trs], a[:, 2], np.minimum(a[:, 2], [tr.z for tr in trs]))
        lo = np.column_stack([c - half, za])
        hi = np.column_stack([c + half, np.maximum(b[:, 2], za + 0.3)])
        return trs, lo, hi

    def frame(self, t: float, boxes: np.ndarray, labels: list[str], scores: np.ndarray, locate_boxes=None) -> list[Track3D]:
        """One camera frame at ``t``: identities from ``boxes`` (B,4) with ``labels``/``scores``; boxes matched to no
        track go to ``locate_boxes(indices) -> (p_field (K,3), sigma (K,), source (K,), beyond_m (K,))`` (None: LiDAR
        only; ``beyond_m``: how far beyond ``p_field`` the box's bottom edge puts its robot, :func:`pipeline.foot_beyond`).
        Returns the confirmed and lost tracks with evidence (:attr:`Track3D.evidence`) predicted to ``t``
        (``tr.last_box``: the box matched this frame)."""
        return self.frame_views(t, [(None, t, boxes, labels, scores, locate_boxes)])

    def frame_views(self, t: float, views: list[tuple]) -> list[Track3D]:
        """Frames of several cameras (issue #19), in time order: ``(view, t_k, boxes, labels, scores, locate_boxes)``
        per camera, ``view`` with ``camera``, ``T_cam_field``, ``pad_px``, ``primary`` (None: this object's camera).
        Each camera's boxes are matched with the tracks at its own frame time; box-only fixes of several cameras on
        one robot (same label within ``0.5 m + 2 sigma``, or another number within 0.3 m: a misread) become one
        inverse-variance weighted fix. :attr:`last_boxes`: track id -> (view index, box index) of its box."""
        tk = self.tracker
        self.last_boxes: dict[int, tuple[int, int]] = {}
        fixes: list[dict] = []
        votes: dict[int, tuple] = {}  # track id -> (track, [(label, weight)]): one vote update per track and tick
        if any(v is None or v.primary for v, *_ in views):
            self.protect_boxes = None
        for k, (view, tv, boxes, labels, scores, locate_boxes) in enumerate(views):
            camera, T_cam_field, pad = (self.camera, self.T_cam_field, self.pad_px) if view is None else (view.camera, view.T_cam_field, view.pad_px)
            for tr in tk.tracks:
                tr.last_box = None
            matched_boxes: set[int] = set()
            primary = view is None or view.primary
            if locate_boxes is not None:
                if len(boxes):
                    locate_boxes = _cached(locate_boxes, len(boxes))
                if primary and self.shadow is not None:
                    self._shadow_update(tv, boxes, labels, scores, locate_boxes)
            if primary:
                self.protect_boxes = boxes if len(boxes) else None
            if camera is not None and len(boxes):
                trs, lo, hi = self.track_hulls(tv)
                if trs:
                    full, depth = project_tracks(camera, T_cam_field, lo, hi)
                    vis, _ = visible_parts(full, depth)
                    for q_, j, q in match_boxes(vis, boxes, pad):
                        tr = trs[q_]
                        tr.last_box = j
                        self.last_boxes[tr.id] = (k, j)
                        matched_boxes.add(j)
                        votes.setdefault(tr.id, (tr, []))[1].append((labels[j], float(scores[j]) * min(1.0, q + 0.3), float(boxes[j, 3] - boxes[j, 1])))
            # a box matched to a track also gives a box-depth fix: the camera ray is not turned by the LiDAR-camera
            # rotation error, so near the track's prediction it is the better measurement and both update the filter;
            # one far from the prediction took its depth from something else (a robot in front) and is ignored
            if matched_boxes and locate_boxes is not None and self.fuse_box_depth:
                idx = sorted(matched_boxes)
                p, sig, src, _ = locate_boxes(idx)
                for n, j in enumerate(idx):
                    tr = next(o for o in tk.tracks if o.last_box == j)
                    if str(src[n]) != "depth" or not np.all(np.isfinite(p[n, :2])) or tr.aerial:
                        continue
                    d = float(np.linalg.norm(tr.x[:2] + tr.x[2:] * (tv - tr.t) - p[n, :2]))
                    if d <= 0.35 + 2.0 * np.hypot(tr.sigma, float(sig[n])):
                        tk._update(tr, p[n, :2], float(sig[n]), tv, tr.z, "depth")
                        tr.n_box, tr.t_box = tr.n_box + 1, tv
            rest = [j for j in range(len(boxes)) if j not in matched_boxes]
            if rest and locate_boxes is not None:
                p, sig, src, beyond = locate_boxes(rest)
                # the box's bottom edge puts its robot a robot's width (+ 2 sigma) or more beyond where it was located
                behind = beyond > self.cfg.exclusion_m + 2.0 * sig
                for n, j in enumerate(rest):
                    if str(src[n]) != "none" and np.all(np.isfinite(p[n, :2])):
                        fixes.append({"k": k, "j": j, "p": p[n], "sigma": float(sig[n]), "source": str(src[n]), "label": labels[j], "score": float(scores[j]), "t": tv,
                                      "h": float(boxes[j, 3] - boxes[j, 1]), "behind": bool(behind[n])})  # fmt: skip
        # box-only fixes for the boxes no LiDAR track explains (one per robot however many cameras box it)
        holder = {tr.label: tr for tr in tk.tracks if tr.label is not None}
        fixed: set[int] = set()  # tracks given a box-only fix this tick: a second fix of that label is another robot
        for fx in box_fix_order(fuse_fixes(fixes), holder):
            tf, label, pf = fx["t"], fx["label"], fx["p"]
            tr = holder.get(label)
            if tr is not None and tf - tr.t_lidar < LIDAR_NOW_S:
                continue  # the LiDAR sees that robot: a box-only fix would only add the box path's errors
            if on_other_robot(tk, tr, label, pf[:2], fx["sigma"], tf, self.cfg.exclusion_m + 2.0 * fx["sigma"], fx.get("behind", False)):
                continue  # its depth is the robot in front, which the LiDAR sees under its own label
            tr = misread_holder(tk, tr if tr is None or tr.id not in fixed else None, label, pf[:2], fx["sigma"], tf, fixed)
            # a LiDAR track where the box puts the robot (its projection missed the box): identity by position
            near = [o for o in tk.tracks if o.n_lidar and tf - o.t_lidar < LIDAR_NOW_S and o.label in (None, label)
                    and np.linalg.norm(o.x[:2] + o.x[2:] * (tf - o.t) - pf[:2]) < 0.8]  # fmt: skip
            got = near[0] if near else tk.update_box(label, pf[:2], fx["sigma"], tf, float(pf[2]), fx["source"], tr)
            if got is None:
                continue
            fixed.add(got.id)
            got.last_box = fx["j"] if fx["k"] == len(views) - 1 else got.last_box
            self.last_boxes[got.id] = (fx["k"], fx["j"])
            votes.setdefault(got.id, (got, []))[1].extend((lab, (0.5 if near else 1.0) * sc, h) for lab, sc, h in fx["votes"])
        for tr, vs in votes.values():
            # decay once per tick however many cameras boxed the track (the votes keep their memory); when several
            # cameras boxed it, each vote counts by how legible the robot is in that camera relative to the best one
            # (a far robot's number in a few pixels of the wide camera is often misread, in the tele it is not)
            leg = np.clip(np.array([v[2] for v in vs]) / LEGIBLE_PX, 0.25, 1.0)
            w = np.array([v[1] for v in vs]) * (leg / leg.max())
            add_votes(tr.votes, vs[0][0], float(w[0]))
            for (lab, _, _), wi in zip(vs[1:], w[1:]):
                tr.votes[lab] = tr.votes.get(lab, 0.0) + float(wi)
        if votes and self.cfg.elsewhere_decay < 1.0:
            # only a box on a track the LiDAR sees now counts against the others: a box-only fix (a false positive, a
            # 3<->4 swap) must not wear down the label of a robot the detector missed this frame
            boxed = {tid: {lab for lab, _, _ in vs} for tid, (tr, vs) in votes.items() if tr.n_lidar and t - tr.t_lidar < LIDAR_NOW_S}
            decay_boxed_elsewhere([tr.votes for tr in tk.tracks], [boxed.get(tr.id, set()) for tr in tk.tracks], self.cfg.elsewhere_decay)
        tk.step(t)
        names = assign_labels([tr.votes for tr in tk.tracks], live=[tr.state != LOST for tr in tk.tracks])
        for tr, lab in zip(tk.tracks, names):
            tr.label = lab
        out = [tr for tr in tk.tracks if tr.state in (CONFIRMED, LOST) and tr.evidence]
        if self.shadow is not None:
            out = self._with_shadow(out, t)
        return self.one_per_robot(out, t)

    # --- the box path's own tracks, for the robots no cluster explains ---------------------------------------------
    def _shadow_update(self, t: float, boxes: np.ndarray, labels: list[str], scores: np.ndarray, locate_boxes) -> None:
        """The box path (`--localise box`) run beside: the best box per label located (box depth, else the ground
        ray), one Kalman track per label (:class:`radarcal.runtime.tracks.TrackManager`)."""
        best: dict[str, int] = {}
        for j, lab in enumerate(labels):
            if lab not in best or scores[j] > scores[best[lab]]:
                best[lab] = j
        idx = sorted(best.values())
        self.shadow_boxes = {}
        if idx:
            p, sig, src, _ = locate_boxes(idx)
            meas = [(labels[j], p[n, :2], float(sig[n]), str(src[n])) for n, j in enumerate(idx) if str(src[n]) != "none"]
            self.shadow_boxes = {labels[j]: j for n, j in enumerate(idx) if str(src[n]) != "none"}
        else:
            meas = []
        self.shadow.update(t, meas)
        self.shadow_t = t

    def _with_shadow(self, out: list[Track3D], t: float) -> list[Track3D]:
        """Per robot and frame the better of the two paths: a label whose LiDAR-first track the LiDAR sees now keeps
        it; any other label the box path tracks is output from the box path's track (what `--localise box` would
        write), the LiDAR-first track of that label (box-only fixes or coasting) is left out."""
        boxed = self.shadow_boxes if self.shadow_t == t else {}
        by_label = {tr.label: tr for tr in out if tr.label is not None}
        res = [tr for tr in out if tr.label is None]
        keep = set()
        n_min = self.tracker.confirm_box_hits  # one box never makes a robot (a false positive, a 3<->4 swap)
        # a label counts from its third consistent fix on, also after the box path restarted its track (its first
        # LiDAR depth moving a ground-ray track, a respawn) as long as the label stays tracked
        self._shadow_ok = {lab for lab in self._shadow_ok if lab in self.shadow.tracks}
        self._shadow_ok |= {lab for lab, s in self.shadow.tracks.items() if s.n_updates >= n_min}
        shadow = {lab: s for lab, s in self.shadow.tracks.items() if lab in self._shadow_ok}
        for lab, tr in by_label.items():
            s = shadow.get(lab)
            if s is None or (self.seen_source(tr, t) == "lidar" and not self._box_better(tr, s, t, lab in boxed)):
                res.append(tr)
                keep.add(lab)
        for lab, s in shadow.items():
            if lab not in keep:
                res.append(self._proxy(lab, s, t, boxed.get(lab)))
        return res

    def _box_better(self, tr: Track3D, s, t: float, boxed: bool) -> bool:
        """A box-depth fix of this frame that the box path's track accepted, more than ``prefer_box_m`` from the
        LiDAR track: the camera ray is not turned by the LiDAR-camera rotation error and the cluster centre is biased
        toward the sensor (most of all an aerial robot's), so the box fix is the better one (measured: docs)."""
        if not boxed or s.t_update != t or s.source != "depth":
            return False
        return float(np.linalg.norm(tr.x[:2] - s.x[:2])) > self.cfg.prefer_box_m

    def _proxy(self, label: str, s, t: float, box: int | None) -> Track3D:
        """A box-path track as an output :class:`Track3D` (stable id per label; measured now or predicted)."""
        pid = self._proxy_ids.setdefault(label, 1_000_000 + len(self._proxy_ids))
        measured = box is not None and s.t_update == t
        x = s.x.copy()  # coasting as the box path does (damping it measured worse: 93.32 vs 93.37 % on seed 1)
        pr = Track3D(pid, x, s.P.copy(), float("nan"), t, s.t_update, state=CONFIRMED, source=s.source if measured else "predicted", label=label)
        pr.t_box = t if measured else -np.inf
        pr.votes = {label: float(s.n_updates)}
        pr.last_box = box if measured else None
        pr.box_label = label
        return pr

    def one_per_robot(self, tracks: list[Track3D], t: float) -> list[Track3D]:
        """One measured entry per robot (issue #19). A RoboMaster ground robot is at most 0.6 x 0.6 m (hero 0.8),
        so two robots' centres are never nearer than ``exclusion_m`` (0.6 m, the inscribed circles touching): output
        tracks (field xy at ``t``) nearer than that are one robot seen twice — a box whose depth is another robot's
        cluster, a box-only track on a LiDAR track's robot, or a second track on one robot's points. Ranked: seen by
        the LiDAR now, then by a box now, then coasting; a labelled track before an unlabelled one; then the fresher
        last measurement, the smaller sigma. The strongest keeps its source; the weaker ones are reported as
        ``predicted`` (:meth:`seen_source`: not a measurement, off the referee map), so their hypotheses (a name, or
        a split cluster's track) stay visible until the two part. Nothing is deleted from the tracker.
        Ground and aerial tracks are separate layers."""
        r = self.cfg.exclusion_m
        if r <= 0 or len(tracks) < 2:
            return tracks
        rank = {"lidar": 2, "depth": 1, "ground": 1, "predicted": 0}
        order = sorted(tracks, key=lambda tr: (-rank[self.seen_source(tr, t)], tr.label is None, -tr.t_seen, tr.sigma, tr.id))
        kept: list[tuple[bool, float, float]] = []  # (aerial, x, y) of the entries kept
        for tr in order:
            x, y = float(tr.x[0]), float(tr.x[1])
            if any(air == tr.aerial and math.hypot(kx - x, ky - y) < r for air, kx, ky in kept):
                tr.outranked_t = t
            else:
                kept.append((tr.aerial, x, y))
        return tracks

    def seen_source(self, tr: Track3D, t: float) -> str:
        """``lidar`` / ``depth`` / ``ground`` when this frame has evidence for the track, else ``predicted`` (also
        for a track another entry of the same robot outranked at ``t``: :meth:`one_per_robot`)."""
        if tr.outranked_t == t:
            return "predicted"
        if t - tr.t_lidar <= self.cfg.seen_lidar_s:
            return "lidar"
        if t - tr.t_box <= self.cfg.seen_box_s:
            return tr.source if tr.source in ("depth", "ground") else "depth"
        return "predicted"


def _cached(locate_boxes, n: int):
    """``locate_boxes`` evaluated once for all ``n`` boxes of a frame; calls with index lists read from it."""
    if getattr(locate_boxes, "cached", False):
        return locate_boxes
    p, sig, src, beyond = locate_boxes(list(range(n)))

    def f(idx):
        idx = list(idx)
        return p[idx], sig[idx], src[idx], beyond[idx]

    f.cached = True
    return f


def fuse_fixes(fixes: list[dict], same_label_m: float = 0.5, other_label_m: float = 0.3) -> list[dict]:
    """Box-only fixes (dicts: k camera index, j box, p (3,), sigma, source, label, score, t) -> one fix per robot.

    Fixes of different cameras join when they carry the same label and lie within ``same_label_m + 2 sigma``, or a
    label of the same colour within ``other_label_m`` (a misread number); each group becomes one fix at the
    inverse-variance weighted mean (sigma ``1 / sqrt(sum 1/sigma^2)``), labelled by the largest score / sigma^2 sum,
    carrying every member's (label, score) vote. Fixes of one camera never join (two boxes are two robots)."""
    groups: list[list[dict]] = []
    for fx in sorted(fixes, key=lambda f: f["sigma"]):
        best, best_d = None, np.inf
        for g in groups:
            if any(m["k"] == fx["k"] for m in g):
                continue
            w = np.array([1.0 / m["sigma"] ** 2 for m in g])
            pg = np.sum([m["p"][:2] * wi for m, wi in zip(g, w)], axis=0) / w.sum()
            d = float(np.linalg.norm(pg - fx["p"][:2]))
            same = any(m["label"] == fx["label"] for m in g)
            colour = any(str(m["label"]).split("_")[0] == str(fx["label"]).split("_")[0] for m in g)
            gate = same_label_m + 2.0 * np.hypot(1.0 / np.sqrt(w.sum()), fx["sigma"]) if same else (other_label_m if colour else -1.0)
            if d <= gate and d < best_d:
                best, best_d = g, d
        if best is None:
            groups.append([fx])
        else:
            best.append(fx)
    out = []
    for g in sorted(groups, key=lambda g: min((m["k"], m["j"]) for m in g)):
        if len(g) == 1:
            out.append({**g[0], "votes": [(g[0]["label"], g[0]["score"], g[0].get("h", LEGIBLE_PX))]})
            continue
        w = np.array([1.0 / m["sigma"] ** 2 for m in g])
        p = np.sum([m["p"] * wi for m, wi in zip(g, w)], axis=0) / w.sum()
        by_label: dict[str, float] = {}
        for m, wi in zip(g, w):
            by_label[m["label"]] = by_label.get(m["label"], 0.0) + m["score"] * wi
        lead = max(g, key=lambda m: (m["label"] == max(by_label, key=by_label.get), 1.0 / m["sigma"]))
        out.append({**lead, "p": p, "sigma": float(1.0 / np.sqrt(w.sum())), "source": "depth" if any(m["source"] == "depth" for m in g) else "ground",
                    "label": max(by_label, key=by_label.get), "t": max(m["t"] for m in g), "behind": any(m.get("behind", False) for m in g), "votes": [(m["label"], m["score"], m.get("h", LEGIBLE_PX)) for m in g]})  # fmt: skip
    return out


def box_fix_order(fixes: list[dict], holder: dict) -> list[dict]:
    """Fused box-only fixes, the one nearest its label's track first (fixes without one last): when one tick has two
    fixes of a label, the one where that track is takes it and the other is another robot (a misread number)."""

    def dist(fx):
        tr = holder.get(fx["label"])
        return np.inf if tr is None else float(np.linalg.norm(tr.x[:2] + tr.x[2:] * (fx["t"] - tr.t) - fx["p"][:2]))

    return sorted(fixes, key=dist)


def misread_holder(tk: Tracker3D, tr: Track3D | None, label: str, xy: np.ndarray, sigma: float, t: float, fixed: set[int]) -> Track3D | None:
    """The track a box-only fix of ``label`` updates: ``tr`` (the label's track) when its gate takes the fix, else a
    track of the same colour with another number whose gate takes it (nearest first; not seen by the LiDAR now, no
    box-only fix yet this tick) — a misread number on a robot the tracker already follows: the fix moves that track
    and its label becomes one more vote (the track's vote memory keeps its name), instead of a new track of the
    misread label beside it. Else ``tr`` (relocated by consistent fixes) or None (a new box-born track)."""

    def gated(o):
        return float(np.linalg.norm(o.x[:2] + o.x[2:] * (t - o.t) - xy)) <= float(tk._gate(o, np.array([sigma]), np.array([t]))[0])

    if tr is not None and gated(tr):
        return tr
    colour = str(label).split("_")[0]
    alt = [o for o in tk.tracks if o.label is not None and o.label != label and o.label.split("_")[0] == colour and o.id not in fixed
           and t - o.t_lidar >= LIDAR_NOW_S and not o.aerial and gated(o)]  # fmt: skip
    if alt:
        return min(alt, key=lambda o: float(np.linalg.norm(o.x[:2] + o.x[2:] * (t - o.t) - xy)))
    return tr


def on_other_robot(tk: Tracker3D, tr: Track3D | None, label: str, xy: np.ndarray, sigma: float, t: float, radius_m: float, behind: bool) -> bool:
    """A box-only fix of ``label`` at field ``xy`` (``sigma`` m) lying within ``radius_m`` (the exclusion radius + 2
    sigma of the fix) of a ground track the LiDAR sees now under another label, nearer than ``tr`` (the label's own
    track, None: none), is that robot's depth (or ground ray) — the box's robot is hidden behind it — when something
    says the box's robot is not there: its own LiDAR-measured track is elsewhere (does not gate the fix; family A seed
    5: two such tele fixes moved blue_2's LiDAR-lost track 4.4 m onto red_1 and blue_4's 9.5 m onto blue_7), or
    ``behind``: the box's bottom edge puts it ``radius_m`` or more beyond the fix, or is hidden
    (:func:`radarcal.runtime.pipeline.foot_beyond`; A 5 with the wide camera alone: blue_4, 25 px high at 25 m, took blue_7's depth at 15.6 m while no blue_4 track existed).
    Without either the box's robot stands where its foot is, beside the other one (`synth field` seed 12: red_3 0.4 m
    behind blue_7, its boxes' depths 0.3 m short on blue_7's points; dropping them lost red_3 for 0.6 s). A fix its
    own LiDAR-measured track gates always goes on (two robots side by side in one cluster: the sample replay's blue_1
    beside blue_2's track); a box-born track's gate does not count, it may be made of such fixes."""
    own = np.inf if tr is None else float(np.linalg.norm(tk.predicted_xy(t, [tr])[0] - xy))
    lidar_track = tr is not None and tr.n_lidar > 0
    if lidar_track and own <= float(tk._gate(tr, np.array([sigma]), np.array([t]))[0]):
        return False
    if not (lidar_track or behind):
        return False
    others = [o for o in tk.tracks if o.label not in (None, label) and not o.aerial and t - o.t_lidar < LIDAR_NOW_S]
    d = np.linalg.norm(tk.predicted_xy(t, others) - xy, axis=1)
    return bool(np.any((d < radius_m) & (d < own)))

"""Radar <-> radar and LiDAR <-> radar extrinsics from trihedral corner reflectors (pure numeric cores).

The method follows a patented procedure for mining trucks (CN, "multi-LiDAR and radar joint calibration for mining
areas") and goes beyond it where it is weak:

1. main frame = the front (main) LiDAR's frame;
2. radar <-> radar: 2D rigid transform (theta, a, b) between radars by nonlinear least squares, initialised in closed
   form (2D Procrustes) -> :func:`procrustes_2d`, :func:`fit_rigid_2d`;
3. LiDAR reflector extraction: ground-plane fit, removal of ground points along the plane normal, Euclidean clusters,
   range gate (4 m), tripod removal, cluster centres -> :func:`fit_ground_plane`, :func:`extract_reflectors`;
4. radar detection filtering into sets A (all in the region), B (seen by two or three radars), C (one radar only)
   -> :func:`filter_detections`;
5. LiDAR <-> radar (theta2, a2, b2) from >= 2 matches, chained into the main frame -> :func:`calibrate_rig`.

Beyond the method: the **slant-range model** (a 2D radar reports the slant range to a reflector that is not at its
mounting height; the fit predicts ``q * sqrt(|q|^2 + dz^2) / |q|`` with ``dz`` from the ground plane and the mounting
height, or estimates the height), robust matching (mutual nearest neighbour under the current estimate, RANSAC over
point pairs), per-reflector residuals, leave-one-out cross-validation, sigma of (theta, a, b), a quantisation report,
and a joint refinement of all radars at once (reflectors seen only by radars enter as free 2D points).

Frames: ``G`` is the ground frame of the main LiDAR (z = ground normal, origin = LiDAR origin dropped onto the
ground, x = LiDAR x projected onto the ground). A 2D radar is level at ``mount_height`` above the ground:
``T_G_radar = [Rz(theta), (a, b, mount_height)]`` and ``T_lidar_radar = T_lidar_G @ T_G_radar``.
2D transforms are ``p_dst = R(theta) p_src + t`` and are named like 4x4 ones (``theta_radar_G`` maps G into radar).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from radarcal import geometry
from radarcal.extrinsics.radar.detections import (
    FRAME_GATE,
    aggregate_frames,
    filter_detections,
    quantisation_report,
)
from radarcal.extrinsics.radar.geometry2d import (
    Fit2D,
    Pose2,
    deslant,
    fit_rigid_2d,
    multipath_of,
    pose2_to_T,
    slant_predict,
)
from radarcal.extrinsics.radar.geometry2d import wrap_angle as _wrap
from radarcal.extrinsics.radar.matching import mutual_nn, robust_match_sets
from radarcal.extrinsics.radar.reflectors import (
    GroundPlane,
    ReflectorExtraction,
    extract_reflectors,
)
from radarcal.extrinsics.radar.validation import leave_one_out, reject_outliers

K_SIGMA = 3.0  # outlier rule: a studentised hold-out residual beyond this many sigma of the others' fit (4x their RMS before issue 18)

__all__ = ["RadarResult", "RigCalibration", "SceneObs", "build_scene_obs", "calibrate_rig"]


@dataclass
class SceneObs:
    """One reflector placement: LiDAR reflector centres (main LiDAR frame) and each radar's detections (its frame)."""

    name: str
    lidar_centres: np.ndarray  # (K,3)
    radar_xy: dict  # radar name -> (M,2)
    ground: GroundPlane | None = None
    raw_radar_xy: dict | None = None  # before frame averaging (for the quantisation report)
    radar_rcs: dict | None = None  # radar name -> (M,) mean RCS (dBsm) of each entry of radar_xy, or None
    radar_counts: dict | None = None  # radar name -> (M,) frames averaged into each entry of radar_xy (None: 1 each)


@dataclass
class RadarResult:
    name: str
    pose_G: Pose2  # T_G_radar in 2D (radar -> ground frame)
    mount_height: float
    T_lidar_radar: np.ndarray  # 4x4, radar -> main LiDAR
    fit: Fit2D  # LiDAR <-> radar fit of the final model (dst = radar measurement, src = ground-frame xy)
    pairwise_pose_ref: Pose2 | None  # (theta1, a1, b1): this radar -> reference radar (patent step 2)
    per_reflector: list  # dicts: scene, lidar index, radar xy, residual (m)
    loo: dict
    rejected: list
    patent_pose_G: Pose2 | None = None  # (theta2, a2, b2) chain before joint refinement
    sigma_G: dict = field(default_factory=dict)  # 1-sigma of T_G_radar's (theta, a, b) (+ height when estimated)


@dataclass
class RigCalibration:
    T_lidar_G: np.ndarray
    radars: dict  # name -> RadarResult
    filter_counts: dict  # scene -> {A, B, C}
    radar_radar: dict  # name -> {pose_ref, rms, n}
    joint: dict  # summary of the joint refinement
    quantisation: dict
    model: str
    notes: list


def _obs_for_radar(scenes, lidar_G, name, pose_G, mount_h, gate, slant, scale=None):
    """Matches of one radar's detections with the LiDAR reflectors under ``pose_G`` (T_G_radar): mutual nearest
    neighbours within ``gate`` or, with ``scale`` = (unit-weight sigma, reference RCS), every detection to its
    nearest reflector within its own RCS-scaled gate (:func:`_associate`). The matched detections' RCS (NaN when
    unknown) is the fifth return value, the frames averaged into each the sixth."""
    src, dst, z, info, rcs, cnt = [], [], [], [], [], []
    inv = pose_G.inverse()
    for si, sc in enumerate(scenes):
        m = np.asarray(sc.radar_xy.get(name, np.zeros((0, 2))), float).reshape(-1, 2)
        pg = lidar_G[si]
        if len(m) == 0 or len(pg) == 0:
            continue
        q = inv.apply(pg[:, :2])
        pred = slant_predict(q, pg[:, 2] - mount_h) if slant else q
        rc = (sc.radar_rcs or {}).get(name)
        nc = (sc.radar_counts or {}).get(name)
        if scale is None:
            pairs = mutual_nn(pred, m, gate)
        else:
            pairs = _associate(pred, m, rc, np.ones(len(m)) if nc is None else np.asarray(nc, float), gate, *scale)
        for i, j in pairs:
            src.append(pg[i, :2]), dst.append(m[j]), z.append(pg[i, 2]), info.append((sc.name, int(i), int(j)))
            rcs.append(np.nan if rc is None else float(rc[j]))
            cnt.append(1 if nc is None else int(nc[j]))
    return np.array(src).reshape(-1, 2), np.array(dst).reshape(-1, 2), np.array(z), info, np.array(rcs), np.array(cnt, float)


MAX_GATE = 1.0  # m: the RCS-scaled gate never exceeds this (reflectors stand ~1 m apart)
GHOST_DB = 4.0  # dB: a detection this much weaker than another of the same reflector is not its echo (ghost, clutter)


def _associate(pred: np.ndarray, m: np.ndarray, rc, counts: np.ndarray, gate: float, sigma_unit: float, rcs_ref: float) -> np.ndarray:
    """Detections ``m`` (frame averages of ``counts`` frames, RCS ``rc`` or None) to predicted reflectors ``pred``:
    each detection to its nearest reflector when closer than 3.4 of its own sigma (99.7 %, 2 dof), ``sigma_unit`` /
    sqrt(RCS weight x frames) (:func:`rcs_weights`) -- a weak echo's noise is larger, so a turned reflector's
    scattered frames all count, at their small weight -- at least ``gate``, at most :data:`MAX_GATE`. Of the
    detections taken by one reflector, those more than :data:`GHOST_DB` weaker than the strongest are not its echo
    (one reflector returns one power; a multipath ghost or clutter beside it is weaker) and dropped.
    Returns (K,2) index pairs (reflector, detection); a reflector may take several detections (a cluster split)."""
    if len(pred) == 0 or len(m) == 0:
        return np.zeros((0, 2), int)
    d = np.linalg.norm(m[:, None, :] - pred[None, :, :], axis=2)
    near = np.argmin(d, axis=1)
    dmin = d[np.arange(len(m)), near]
    w = np.ones(len(m)) if rc is None else rcs_weights(rc, ref=rcs_ref)
    sig = sigma_unit / np.sqrt(w * np.maximum(counts, 1))
    ok = dmin < np.clip(3.4 * sig, gate, MAX_GATE)
    if rc is not None:
        for i in np.unique(near[ok]):  # reflectors (few)
            mine = np.nonzero(ok & (near == i))[0]
            top = mine[np.argmax(rc[mine])]
            ok[mine[rc[mine] < rc[top] - GHOST_DB]] = False
    j = np.nonzero(ok)[0]
    return np.stack([near[j], j], axis=1)


def rcs_weights(rcs: np.ndarray, floor: float = 1e-3, ref: float | None = None) -> np.ndarray:
    """Relative inverse variances of radar detections from their RCS (dBsm): a radar's position noise grows as the
    echo weakens (variance ~ 1 / SNR ~ 10^(-RCS/10)); relative to ``ref`` (default: the 90th percentile of the
    matched detections' RCS), capped at 1 (strong echoes all count the same), ``floor`` below. Ones when the RCS is
    unknown."""
    rcs = np.asarray(rcs, float)
    if len(rcs) == 0 or not np.isfinite(rcs).any():
        return np.ones(len(rcs))
    ref = float(np.nanpercentile(rcs, 90)) if ref is None else float(ref)
    w = 10 ** ((np.where(np.isfinite(rcs), rcs, ref) - ref) / 10)
    return np.clip(w, floor, 1.0)


class _Matched(NamedTuple):
    """One radar's LiDAR-matched detections after the per-radar fit (ground-frame xy ``src`` / height ``z``, radar
    measurement ``dst``), with the inlier mask, rejections, fit keywords, weights and RCS of each match."""

    src: np.ndarray  # (N,2) reflector xy in G
    dst: np.ndarray  # (N,2) radar detection (radar frame)
    z: np.ndarray  # (N,) reflector height in G
    info: list  # (scene, lidar index, radar index) per match
    keep: np.ndarray  # (N,) bool, inliers
    rejected: list  # (match index, reason)
    fit_kw: dict  # height keywords of fit_rigid_2d
    weights: np.ndarray  # (N,) relative inverse variances
    rcs: np.ndarray  # (N,) dBsm, NaN when unknown
    rcs_ref: float | None  # dBsm of unit weight (None: RCS unknown)


@dataclass
class _Rig:
    """What the steps of :func:`calibrate_rig` share: the scenes in the ground frame G and the radars' heights."""

    scenes: Sequence[SceneObs]
    radar_names: list
    reference: str
    slant: bool
    gate: float
    ground: GroundPlane | None
    T_lidar_G: np.ndarray
    lidar_G: list  # per scene (K,3) reflector centres in G
    z_nominal: float  # median reflector height in G (m)
    init_G: dict  # radar -> Pose2 T_G_radar from init_T_lidar_radar
    heights: dict  # radar -> mounting height above ground (m) or None (estimated)
    h_guess: float  # starting height of a radar without one
    notes: list

    def deslant(self, name: str, m) -> np.ndarray:
        """Radar ``name``'s detections (its frame) as in-plane positions at the reflectors' nominal height."""
        if not self.slant or (self.heights[name] is None and self.ground is None):
            return np.asarray(m, float).reshape(-1, 2)  # unknown plane height: match on the raw (slant) positions
        h = self.heights[name] if self.heights[name] is not None else self.h_guess
        return deslant(m, self.z_nominal - h)

    def detections(self, sc: SceneObs, name: str) -> np.ndarray:
        return self.deslant(name, sc.radar_xy.get(name, np.zeros((0, 2))))


def calibrate_rig(
    scenes: Sequence[SceneObs],
    radar_names: Sequence[str],
    mount_heights: dict,
    reference: str | None = None,
    init_T_lidar_radar: dict | None = None,
    model: str = "slant",
    gate: float = 0.35,
    forward: tuple[float, float] = (0.0, 5.0),
    lateral: tuple[float, float] = (-5.0, 5.0),
    outlier_threshold: float = 0.15,
    joint: bool = True,
    lidar_range_gate: float | None = 4.0,
    ground: GroundPlane | None = None,
) -> RigCalibration:
    """Every radar into the main LiDAR frame (patent steps 2-5, then the improvements).

    ``model``: ``"slant"`` (radar mounting heights + ground plane; default), ``"planar"`` (the patent: reflector
    centres' z dropped in the LiDAR frame, no slant). ``mount_heights``: radar scanning-plane height above the ground
    (m); a radar without one gets it estimated (slant model). ``init_T_lidar_radar``: optional nominal poses (used to
    pick correspondences; without them RANSAC over pairs decides).
    The steps, in the patent's order, are the private functions below (ground frame, radar<->radar, A/B/C filter,
    LiDAR<->reference radar, per-radar slant fit with outliers, joint refinement, results).
    """
    if not scenes:
        raise ValueError("no scenes")
    rig = _rig_in_ground_frame(scenes, radar_names, mount_heights, reference, init_T_lidar_radar, model, gate, ground)
    pose_ref, radar_radar = _radar_radar(rig)
    filter_counts, merged = _filter_scenes(rig, pose_ref, forward, lateral)
    patent_G = _lidar_reference_radar(rig, pose_ref, merged)
    pose_G = _start_poses(rig, patent_G)
    fits, matched = _fit_radars(rig, pose_G, outlier_threshold)
    joint_info = {"enabled": bool(joint), "free_points": 0, "n_obs": 0}
    if joint and len(fits) >= 2:
        in_region = _radar_only_region(pose_G, rig.reference, forward, lateral, lidar_range_gate)
        pose_G, rig.heights, joint_info = _joint_refine(scenes, rig.lidar_G, pose_G, rig.heights, fits, matched, rig.slant, gate, rig.z_nominal,
                                                        in_region)
    results = {r: _radar_result(rig, r, matched[r], pose_G, bool(joint_info.get("free_points")), radar_radar, patent_G) for r in fits}
    allxy = np.concatenate([np.asarray(v, float).reshape(-1, 2) for s in scenes for v in (s.raw_radar_xy or s.radar_xy).values()]) if scenes else np.zeros((0, 2))
    return RigCalibration(rig.T_lidar_G, results, filter_counts, radar_radar, joint_info, quantisation_report(allxy), model, rig.notes)


def _rig_in_ground_frame(scenes, radar_names, mount_heights, reference, init_T_lidar_radar, model, gate, ground) -> _Rig:
    """Ground frame G (mean of the scenes' ground planes unless ``ground`` is given; identity for the planar model),
    the LiDAR reflectors and the initial poses in it, the radars' heights and the starting height of unknown ones."""
    notes: list[str] = []
    radar_names = list(radar_names)
    reference = reference or (radar_names[len(radar_names) // 2])
    slant = model == "slant"
    if model == "planar":
        T_lidar_G = np.eye(4)
    else:
        planes = [s.ground for s in scenes if s.ground is not None]
        if ground is None and planes:
            n = np.mean([g.normal for g in planes], axis=0)
            n /= np.linalg.norm(n)
            ground = GroundPlane(n, float(np.mean([g.d for g in planes])), int(sum(g.inliers for g in planes)), float(np.mean([g.rms for g in planes])))
        T_lidar_G = ground.T_lidar_ground() if ground is not None else np.eye(4)
        if ground is None:
            notes.append("no ground plane: the LiDAR frame is taken as level (z up) and heights are LiDAR z")
    T_G_lidar = geometry.invert_T(T_lidar_G)
    lidar_G = [geometry.transform_points(T_G_lidar, np.asarray(s.lidar_centres, float).reshape(-1, 3)) for s in scenes]
    all_z = np.concatenate([p[:, 2] for p in lidar_G]) if lidar_G else np.zeros(0)
    z_nominal = float(np.median(all_z)) if len(all_z) else 0.0
    init_G: dict[str, Pose2] = {}
    for r in radar_names:
        if init_T_lidar_radar and r in init_T_lidar_radar and init_T_lidar_radar[r] is not None:
            init_G[r] = Pose2.from_T(T_G_lidar @ np.asarray(init_T_lidar_radar[r], float))
    heights = {r: (None if mount_heights.get(r) is None else float(mount_heights[r])) for r in radar_names}
    for r in radar_names:
        if slant and heights[r] is None:
            notes.append(f"{r}: no mounting height given: estimated from the slant model (only |dz| is observable)")
    # unknown height: start below the reflectors (bumper height); dz = 0 is a stationary point of the slant model
    h_guess = 0.5 if abs(z_nominal - 0.5) > 0.15 else z_nominal - 0.4
    if slant and ground is None:  # heights are LiDAR z: no bumper height to start from; 0.4 m below the reflectors
        h_guess = z_nominal - 0.4
    return _Rig(scenes, radar_names, reference, slant, gate, ground, T_lidar_G, lidar_G, z_nominal, init_G, heights, h_guess, notes)


def _radar_radar(rig: _Rig) -> tuple[dict, dict]:
    """Patent step 2: each radar into the reference radar, (theta1, a1, b1) from their common reflectors. Returns the
    poses (radar -> reference) of the linked radars and the per-radar fit summary."""
    radar_radar: dict[str, dict] = {}
    pose_ref: dict[str, Pose2] = {rig.reference: Pose2(0.0, np.zeros(2))}
    for r in rig.radar_names:
        if r == rig.reference:
            continue
        init = None
        if rig.reference in rig.init_G and r in rig.init_G:
            init = rig.init_G[rig.reference].inverse().compose(rig.init_G[r])
        A_ = [rig.detections(sc, r) for sc in rig.scenes]
        B_ = [rig.detections(sc, rig.reference) for sc in rig.scenes]
        pairs_l, _ = robust_match_sets(A_, B_, init=init, gate=rig.gate)
        src = [a[p[:, 0]] for a, p in zip(A_, pairs_l) if len(p)]
        dst = [b[p[:, 1]] for b, p in zip(B_, pairs_l) if len(p)]
        if src and sum(len(s) for s in src) >= 2:
            s_, d_ = np.concatenate(src), np.concatenate(dst)
            f = fit_rigid_2d(s_, d_)
            pose_ref[r] = f.pose
            radar_radar[r] = {"pose_ref": f.pose, "rms": f.rms, "n": f.n, "sigma": f.sigma}
        else:
            rig.notes.append(f"{r}: no common reflectors with {rig.reference}: calibrated against the LiDAR only")
    return pose_ref, radar_radar


def _filter_scenes(rig: _Rig, pose_ref: dict, forward, lateral) -> tuple[dict, list]:
    """Patent step 4: every scene's detections in the reference radar frame, filtered into sets A/B/C. Returns the
    counts per scene and, per scene, (cluster means (K,2) in the reference frame, seen by >= 2 radars (K,))."""
    filter_counts = {}
    merged = []
    for sc in rig.scenes:
        pts = [pose_ref[r].apply(rig.detections(sc, r)) if r in pose_ref else np.zeros((0, 2)) for r in rig.radar_names]
        fr = filter_detections(pts, forward, lateral, rig.gate)
        filter_counts[sc.name] = fr.counts()
        nb = int((fr.cluster_radars >= 2).sum())
        if nb < 2:
            rig.notes.append(f"scene {sc.name}: {nb} reflector(s) seen by two or more radars (set B): set A used for the LiDAR match")
        if len(fr.C) > len(fr.B):
            rig.notes.append(f"scene {sc.name}: more single-radar detections (C = {len(fr.C)}) than multi-radar ones (B = {len(fr.B)}): ghosts or radars that see too little")
        merged.append((fr.cluster_means, fr.cluster_radars >= 2))
    return filter_counts, merged


def _lidar_reference_radar(rig: _Rig, pose_ref: dict, merged: list) -> dict:
    """Patent step 5: the reference radar into G, (theta2, a2, b2), from set B (set A when B has fewer than two),
    chained to every linked radar. Returns radar -> Pose2 T_G_radar."""
    b_sets = [means[multi] if multi.sum() >= 2 else means for means, multi in merged]
    pairs_l, _ = robust_match_sets(b_sets, [p[:, :2] for p in rig.lidar_G], init=rig.init_G.get(rig.reference), gate=rig.gate)
    src = [b[p[:, 0]] for b, p in zip(b_sets, pairs_l) if len(p)]
    dst = [g[p[:, 1], :2] for g, p in zip(rig.lidar_G, pairs_l) if len(p)]
    if sum(len(x) for x in src) < 2:
        raise ValueError("fewer than 2 reflectors matched between the LiDAR and the radars")
    f_ref = fit_rigid_2d(np.concatenate(src), np.concatenate(dst))  # ref radar -> G
    return {r: f_ref.pose.compose(pose_ref[r]) for r in pose_ref}


def _start_poses(rig: _Rig, patent_G: dict) -> dict:
    """Starting T_G_radar of each radar for its own fit: the patent chain, or the initial guess where the chain is
    far from it or missing; radars with neither are skipped (noted)."""
    pose_G = dict(patent_G)
    init_G = rig.init_G
    for r in rig.radar_names:
        if r in pose_G and r in init_G:  # a patent chain far from the radar's own guess: a wrong match, start from the guess
            d_th = abs(float(_wrap(pose_G[r].theta - init_G[r].theta)))
            d_t = float(np.linalg.norm(pose_G[r].t - init_G[r].t))
            if d_th > np.radians(10.0) or d_t > 0.5:
                rig.notes.append(f"{r}: the radar-radar chain is {np.degrees(d_th):.1f} deg / {d_t:.2f} m from its initial_T_main: matched from the guess instead")
                pose_G[r] = init_G[r]
        if r not in pose_G:
            if r in init_G:
                pose_G[r] = init_G[r]
            else:
                rig.notes.append(f"{r}: no initial pose and no radar-radar link: skipped")
                continue
    return pose_G


def _fit_radars(rig: _Rig, pose_G: dict, outlier_threshold: float) -> tuple[dict, dict]:
    """Every radar's own LiDAR-anchored fit (final model), updating ``pose_G`` and ``rig.heights`` in place.
    Returns radar -> Fit2D (maps G -> radar) and radar -> :class:`_Matched`."""
    fits: dict[str, Fit2D] = {}
    matched: dict[str, _Matched] = {}
    for r in list(pose_G):
        _fit_one_radar(rig, r, pose_G, outlier_threshold, fits, matched)
        if r not in fits:
            rig.notes.append(f"{r}: fewer than 2 reflectors matched to the LiDAR: not calibrated")
        if r in fits and rig.heights[r] is None and rig.slant:
            _try_mirror_height(rig, r, pose_G, fits, matched[r])
    return fits, matched


def _fit_one_radar(rig: _Rig, r: str, pose_G: dict, outlier_threshold: float, fits: dict, matched: dict) -> None:
    """Match radar ``r`` to the LiDAR reflectors under its current pose (mutual nearest neighbours first, then every
    detection within its own RCS-scaled gate, :func:`_associate`, at the robust noise scale of the previous fit),
    reject outliers, fit; up to four rounds until the pose stops moving. Writes ``pose_G[r]``, ``fits[r]`` and
    ``matched[r]``."""
    slant = rig.slant
    h = rig.heights[r] if rig.heights[r] is not None else rig.h_guess
    scale = None
    rcs_ref = None
    for _ in range(4):
        s_, d_, z_, info, rc_, n_ = _obs_for_radar(rig.scenes, rig.lidar_G, r, pose_G[r], h, rig.gate, slant, scale)
        if len(s_) < 2:
            break
        if rcs_ref is None and np.isfinite(rc_).any():
            rcs_ref = float(np.nanpercentile(rc_, 90))  # the strong echoes of the first (mutual) matches: fixed from here
        w_ = rcs_weights(rc_, ref=rcs_ref) * n_  # a mean of n frames counts n times
        kw = _fit_kw(slant, rig.heights[r], h)
        keep, rej = reject_outliers(s_, d_, threshold=outlier_threshold, weights=w_, k_sigma=K_SIGMA, **({**kw, "src_z": z_} if slant else kw))
        f = fit_rigid_2d(s_[keep], d_[keep], src_z=z_[keep] if slant else None, weights=w_[keep], **kw)
        # f maps G -> radar; pose_G is radar -> G
        new = f.pose.inverse()
        h = f.height if f.height is not None else h
        converged = scale is not None and abs(_wrap(new.theta - pose_G[r].theta)) < 1e-10 and np.allclose(new.t, pose_G[r].t, atol=1e-9)
        pose_G[r] = new
        fits[r] = f
        matched[r] = _Matched(s_, d_, z_, info, keep, rej, kw, w_, rc_, rcs_ref)
        if converged:
            break
        # robust unit-weight noise scale (median 2D residual length = 1.177 sigma), at least 1 cm
        unit = np.sqrt(w_[keep]) * np.linalg.norm(f.residuals, axis=1)
        scale = (max(float(np.median(unit)) / 1.177, 0.01), rcs_ref if rcs_ref is not None else 0.0)


def _try_mirror_height(rig: _Rig, r: str, pose_G: dict, fits: dict, m: _Matched) -> None:
    """Estimated height: only |dz| is observable, but the slant model is not exactly symmetric: try the mirror height
    too and keep the better fit; sets ``rig.heights[r]``."""
    zc = float(np.average(m.z[m.keep], weights=m.weights[m.keep]))
    g = fit_rigid_2d(m.src[m.keep], m.dst[m.keep], src_z=m.z[m.keep], weights=m.weights[m.keep], estimate_height=True, height_init=2 * zc - fits[r].height)
    if g.rms < fits[r].rms - 1e-9:
        fits[r] = g
        pose_G[r] = g.pose.inverse()
    rig.heights[r] = float(fits[r].height)


def _radar_only_region(pose_G: dict, reference: str, forward, lateral, lidar_range_gate):
    """Mask function over (N,2) points in G: inside the reference radar's forward/lateral region and, with a LiDAR
    range gate, beyond it (inside the gate a reflector would have a LiDAR cluster)."""
    ref_inv = pose_G[reference].inverse() if reference in pose_G else Pose2(0.0, np.zeros(2))

    def in_region(p_G):
        q = ref_inv.apply(p_G)
        inside = (q[:, 0] > forward[0]) & (q[:, 0] < forward[1]) & (q[:, 1] > lateral[0]) & (q[:, 1] < lateral[1])
        if lidar_range_gate is not None:
            inside &= np.linalg.norm(p_G, axis=1) > lidar_range_gate - 0.2
        return inside

    return in_region


def _radar_result(rig: _Rig, r: str, m: _Matched, pose_G: dict, had_free_points: bool, radar_radar: dict, patent_G: dict) -> RadarResult:
    """Radar ``r``'s result: LiDAR-anchored fit at the final height (sigma, leave-one-out, per-reflector residuals);
    the pose is the joint one unless it strays beyond 99 % (chi-square, 3 dof) of that fit. Writes ``pose_G[r]``."""
    slant = rig.slant
    s_, d_, z_, info, keep, rej, w_ = m.src, m.dst, m.z, m.info, m.keep, m.rejected, m.weights
    h = rig.heights[r]
    kw2 = _fit_kw(slant, h, h)
    # the pose is the joint one (same when no radar-only reflectors exist)
    f = fit_rigid_2d(s_[keep], d_[keep], src_z=z_[keep] if slant else None, init=pose_G[r].inverse(), weights=w_[keep], **kw2)
    if not had_free_points:
        pose_G[r] = f.pose.inverse()
    else:  # the joint pose must agree with the radar's own LiDAR-anchored fit (radar-only points can be wrong)
        jp = pose_G[r].inverse()
        dx = np.array([float(_wrap(jp.theta - f.pose.theta)), *(jp.t - f.pose.t)])
        try:
            d2 = float(dx @ np.linalg.solve(f.cov[:3, :3], dx))
        except np.linalg.LinAlgError:
            d2 = np.inf
        if d2 > 11.34:  # chi-square, 3 dof, 99 %
            rig.notes.append(f"{r}: the joint refinement moved it {np.sqrt(d2):.1f} sigma from its own LiDAR-anchored fit: that fit kept")
            pose_G[r] = f.pose.inverse()
    loo = leave_one_out(s_[keep], d_[keep], weights=w_[keep], **({**kw2, "src_z": z_[keep]} if slant else kw2))
    q = pose_G[r].inverse().apply(s_)
    pred = slant_predict(q, z_ - h) if slant else q
    res_vec = d_ - pred
    resid = np.linalg.norm(res_vec, axis=1)
    f.residuals = res_vec[keep]
    f.rms = float(np.sqrt(np.mean(resid[keep] ** 2))) if keep.any() else float("nan")
    kidx = np.cumsum(keep) - 1
    per = []
    for k, (scn, i, j) in enumerate(info):  # per reflector observation (few)
        per.append({"scene": scn, "lidar_index": i, "radar_index": j, "radar_xy": d_[k], "residual_m": float(resid[k]), "used": bool(keep[k]),
                    "holdout_residual_m": float(loo["holdout_residuals"][kidx[k]]) if keep[k] and len(loo["holdout_residuals"]) else float("nan")})
    mh = h if h is not None else 0.0
    T_G_radar = pose2_to_T(pose_G[r], mh if slant else 0.0)
    return RadarResult(r, pose_G[r], mh, rig.T_lidar_G @ T_G_radar, f, radar_radar.get(r, {}).get("pose_ref"), per, loo,
                       [(info[i], why) for i, why in rej], patent_G.get(r), f.inverse_sigma())


def _fit_kw(slant: bool, known_h, h_guess) -> dict:
    if not slant:
        return {}
    if known_h is None:
        return {"estimate_height": True, "height_init": float(h_guess)}
    return {"height": float(known_h)}


def _joint_refine(scenes, lidar_G, pose_G, heights, fits, keepinfo, slant, gate, z_nominal, in_region):
    """All radar poses at once. Observations: every radar's matched LiDAR reflectors (kept ones, ``keepinfo``: radar
    -> :class:`_Matched`), plus detections of reflectors that two or more radars see but the LiDAR does not (free 2D
    points at the median reflector height). Returns the new poses T_G_radar, heights and a summary."""
    names = list(fits)
    free_init, free_obs = _free_points(scenes, lidar_G, names, pose_G, heights, keepinfo, slant, gate, z_nominal, in_region)
    prob = _JointProblem.build(names, pose_G, heights, keepinfo, free_init, slant, z_nominal)
    all_obs = _FreeObs(np.array([o[0] for o in free_obs], int), np.array([o[1] for o in free_obs], int), np.array([o[2] for o in free_obs]).reshape(-1, 2),
                       np.array([o[3] for o in free_obs], float))
    x, obs, dropped = _solve_dropping_outliers(prob, all_obs)
    free_init = [f for i, f in enumerate(free_init) if i not in dropped]
    P, H, F = prob.unpack(x)
    new_pose = {r: Pose2(float(_wrap(P[k, 0])), P[k, 1:].copy()) for k, r in enumerate(names)}
    new_h = {r: (float(H[k]) if (slant or heights[r] is not None) else None) for k, r in enumerate(names)}
    for r in heights:
        if r not in new_h:
            new_h[r] = heights[r]
    rr = prob.resid(x, obs)
    return new_pose, new_h, {"enabled": True, "free_points": len(free_init), "free_points_dropped": len(dropped), "n_obs": int(len(rr) // 2), "rms": float(np.sqrt(np.mean(rr.reshape(-1, 2) ** 2) * 2)) if len(rr) else 0.0}


def _free_points(scenes, lidar_G, names, pose_G, heights, keepinfo, slant, gate, z_nominal, in_region) -> tuple[list, list]:
    """Radar-only reflectors: per scene, the detections no LiDAR match used (strong enough, inside ``in_region``,
    not on a LiDAR reflector's echo path -- its multipath ghosts, :func:`multipath_of` --, in G under the current
    poses) clustered across radars; a cluster seen by >= 2 radars, once each, is a free point.
    Returns the free points' starting xy in G and the observations (radar index, free point index, measurement,
    relative inverse variance: RCS weight x frames, as the radar's LiDAR matches)."""
    free_obs = []
    free_init = []
    for si, sc in enumerate(scenes):
        pts, rid, mids, wts = [], [], [], []
        for k, r in enumerate(names):
            m = np.asarray(sc.radar_xy.get(r, np.zeros((0, 2))), float).reshape(-1, 2)
            if len(m) == 0:
                continue
            used = {j for (scn, i, j), kp in zip(keepinfo[r].info, keepinfo[r].keep) if scn == sc.name}
            un = np.array([j for j in range(len(m)) if j not in used], int)
            rc = (sc.radar_rcs or {}).get(r)
            if rc is not None and len(un) and np.isfinite(keepinfo[r].rcs).any():
                # weak echoes (clutter, multipath) are not radar-only reflectors
                un = un[np.asarray(rc, float)[un] >= np.nanpercentile(keepinfo[r].rcs, 10) - 6.0]
            h = heights[r] if heights[r] is not None else 0.0
            if slant and len(un) and len(lidar_G[si]):  # a LiDAR reflector's echo or its ground-bounce ghost is no free point
                pg = lidar_G[si]
                un = un[multipath_of(m[un], pose_G[r].inverse().apply(pg[:, :2]), pg[:, 2], h, gate) < 0]
            if len(un) == 0:
                continue
            mg = pose_G[r].apply(deslant(m[un], z_nominal - h) if slant else m[un])
            inside = in_region(mg)
            un, mg = un[inside], mg[inside]
            if len(un) == 0:
                continue
            nc = (sc.radar_counts or {}).get(r)
            w = (np.ones(len(un)) if rc is None else rcs_weights(np.asarray(rc, float)[un], ref=keepinfo[r].rcs_ref)) * (1 if nc is None else np.asarray(nc, float)[un])
            pts.append(mg), rid.append(np.full(len(un), k)), mids.append(m[un]), wts.append(w)
        if not pts:
            continue
        fr = filter_detections([np.concatenate(pts)[np.concatenate(rid) == k] for k in range(len(names))], (-np.inf, np.inf), (-np.inf, np.inf), gate)
        allm = np.concatenate(mids)
        allr = np.concatenate(rid)
        allw = np.concatenate(wts)
        order = np.argsort(allr, kind="stable")  # filter_detections concatenates radar by radar
        allm, allr, allw = allm[order], allr[order], allw[order]
        for c in np.nonzero(fr.cluster_radars >= 2)[0]:
            members = np.nonzero(fr.cluster == c)[0]
            if len(np.unique(allr[members])) != len(members):
                continue  # two detections of one radar in a cluster: ambiguous, skip
            fid = len(free_init)
            free_init.append(fr.cluster_means[c])
            for mi in members:
                free_obs.append((int(allr[mi]), fid, allm[mi], float(allw[mi])))
    return free_init, free_obs


class _FreeObs(NamedTuple):
    """Radar detections of free points: radar index (N,), free point index (N,), measurement xy (N,2) radar frame,
    relative inverse variance (N,)."""

    radar: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    w: np.ndarray


@dataclass
class _JointProblem:
    """Parameter layout of the joint refinement: x = [nr x (theta, a, b) T_G_radar | nr heights | free points xy in G];
    heights of radars with a known one stay fixed."""

    nr: int
    slant: bool
    z_nominal: float
    est_h: list  # per radar: height estimated
    fixed_h: np.ndarray  # per radar: known height (0 when estimated)
    anchored: list  # per radar: (index, src xy G, dst radar xy, src z, sqrt weight (N,1)) of its kept LiDAR matches
    x0: np.ndarray

    @classmethod
    def build(cls, names, pose_G, heights, keepinfo, free_init, slant, z_nominal) -> _JointProblem:
        est_h = [slant and heights[r] is None for r in names]
        x0 = np.concatenate([np.concatenate([pose_G[r].as_array() for r in names]), np.array([heights[r] or 0.0 for r in names]), np.array(free_init).ravel()])
        anchored = []
        for k, r in enumerate(names):
            s_, d_, z_, keep, w_ = keepinfo[r].src, keepinfo[r].dst, keepinfo[r].z, keepinfo[r].keep, keepinfo[r].weights
            anchored.append((k, s_[keep], d_[keep], z_[keep], np.sqrt(w_[keep])[:, None]))
        fixed_h = np.array([heights[r] if heights[r] is not None else 0.0 for r in names])
        return cls(len(names), slant, z_nominal, est_h, fixed_h, anchored, x0)

    def unpack(self, x):
        nr = self.nr
        P = x[:3 * nr].reshape(nr, 3)
        H = np.where(self.est_h, x[3 * nr:4 * nr], self.fixed_h)
        F = x[4 * nr:].reshape(-1, 2)
        return P, H, F

    def pred_radar(self, P, H, k, pg_xy, pz):
        """Radar ``k``'s predicted measurement of points ``pg_xy`` (G) at heights ``pz``."""
        inv = Pose2(P[k, 0], P[k, 1:]).inverse()
        q = inv.apply(pg_xy)
        return slant_predict(q, pz - H[k]) if self.slant else q

    def free_errors(self, P, H, F, obs: _FreeObs, k: int) -> np.ndarray:
        """(n,2) residuals of radar ``k``'s free-point observations (``obs.radar == k``), at unit weight."""
        sel = obs.radar == k
        return (self.pred_radar(P, H, k, F[obs.point[sel]], np.full(sel.sum(), self.z_nominal)) - obs.xy[sel]) * np.sqrt(obs.w[sel])[:, None]

    def resid(self, x, obs: _FreeObs) -> np.ndarray:
        P, H, F = self.unpack(x)
        out = []
        for k, s_, d_, z_, sw in self.anchored:  # loop over radars
            out.append(((self.pred_radar(P, H, k, s_, z_) - d_) * sw).ravel())
        for k in range(self.nr):
            if (obs.radar == k).any():
                out.append(self.free_errors(P, H, F, obs, k).ravel())
        return np.concatenate(out)


def _solve_dropping_outliers(prob: _JointProblem, all_obs: _FreeObs):
    """Solve; drop radar-only points that do not fit (beyond 4x the anchored RMS: multipath, clutter seen twice);
    again (up to four solves). Returns the solution x, the observations it used and the dropped free points."""
    nr = prob.nr
    free_mask = np.ones(len(prob.x0), bool)
    free_mask[3 * nr:4 * nr] = prob.est_h
    dropped: set = set()
    for _round in range(4):
        live = np.array([f not in dropped for f in all_obs.point], bool)
        obs = _FreeObs(all_obs.radar[live], all_obs.point[live], all_obs.xy[live], all_obs.w[live])
        mask = free_mask.copy()
        for f in dropped:
            mask[4 * nr + 2 * f:4 * nr + 2 * f + 2] = False

        def resid_free(xf, mask=mask, obs=obs):
            x = prob.x0.copy()
            x[mask] = xf
            return prob.resid(x, obs)

        sol = least_squares(resid_free, prob.x0[mask], method="trf", x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12)
        x = prob.x0.copy()
        x[mask] = sol.x
        P, H, F = prob.unpack(x)
        anch = np.concatenate([((prob.pred_radar(P, H, k, s_, z_) - d_) * sw).ravel() for k, s_, d_, z_, sw in prob.anchored]) if prob.anchored else np.zeros(0)
        scale = max(float(np.sqrt(np.mean(anch**2) * 2)) if len(anch) else 0.0, 0.01)
        bad = set()
        for k in range(nr):
            sel = obs.radar == k
            if sel.any():
                e = np.linalg.norm(prob.free_errors(P, H, F, obs, k), axis=1)
                bad |= {int(f) for f, ei in zip(obs.point[sel], e) if ei > 4 * scale}
        if not bad:
            break
        dropped |= bad
    return x, obs, dropped


def build_scene_obs(name: str, main_points: np.ndarray, radar_xy: dict, range_gate: float = 4.0, ground_tol: float = 0.05, cluster_tol: float = 0.12,
                    head_size: float = 0.35, offset: float = 0.0, aggregate: bool = True, aggregate_gate: float = FRAME_GATE, radar_rcs: dict | None = None,
                    edge: float | None = None, intensity: np.ndarray | None = None, frames: dict | None = None) -> tuple[SceneObs, ReflectorExtraction, dict]:
    """One placement's observations from raw arrays: reflector extraction on the main LiDAR cloud (``edge``: the
    trihedral's edge when known, ``intensity`` per point when the cloud has it) and, when a radar reported several
    frames, averaging of its repeated detections (:func:`aggregate_frames`, split by RCS when ``radar_rcs`` gives
    it; ``frames``: radar name -> its :func:`~radarcal.extrinsics.radar.detections.frames_per_source` over the
    session, None: each call's own estimate). Returns the :class:`SceneObs`, the extraction details and per-radar
    frame counts."""
    ext = extract_reflectors(main_points, range_gate=range_gate, ground_tol=ground_tol, cluster_tol=cluster_tol, head_size=head_size, offset=offset,
                             edge=edge, intensity=intensity)
    out, counts, rcs_out = {}, {}, {}
    for r, xy in radar_xy.items():
        xy = np.asarray(xy, float).reshape(-1, 2)
        rc = None if radar_rcs is None or radar_rcs.get(r) is None else np.asarray(radar_rcs[r], float).reshape(-1)
        if rc is not None and not np.isfinite(rc).any():
            rc = None
        if aggregate and len(xy):
            if rc is not None:
                means, c, rm = aggregate_frames(xy, gate=aggregate_gate, rcs=rc, frames=(frames or {}).get(r))
            else:
                (means, c), rm = aggregate_frames(xy, gate=aggregate_gate, frames=(frames or {}).get(r)), None
            if c.max() > 1:
                out[r], counts[r], rcs_out[r] = means, c, rm
                continue
        out[r], counts[r], rcs_out[r] = xy, np.ones(len(xy), int), rc
    raw = {r: np.asarray(xy, float).reshape(-1, 2) for r, xy in radar_xy.items()}
    return SceneObs(name, ext.centres, out, ext.ground, raw, rcs_out, counts), ext, counts

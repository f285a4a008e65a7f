"""Held-out features of issue 18: tripod legs, reflectors turned away, multipath split by RCS, RCS weights, the
LiDAR-LiDAR observability check, and the pooled accuracy on generated sessions against the ideal fit."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.radar import aggregate_frames, extract_reflectors
from radarcal.extrinsics.radar.lidar_lidar import axis_name, refine_with_reflectors
from radarcal.extrinsics.radar.reflectors import fit_trihedral, linear_fraction
from radarcal.extrinsics.radar.rig import rcs_weights
from radarcal.synth.radar import (
    RadarSceneSpec,
    generate_radar_session,
    reflector_offset,
    trihedral_points,
)


@pytest.mark.parametrize("sampling", ["grid", "random"])
def test_tripod_legs_rejected_turned_reflectors_exact(sampling):
    spec = RadarSceneSpec(n_scenes=1, reflectors_per_scene=3, radar_sigma=0.0, lidar_noise=0.0, tripod="legs", reflector_turn_deg=(35.0, 50.0),
                          plate_sampling=sampling, init_error=None, seed=31)
    ses = generate_radar_session(spec)
    rig = ses.rig
    cloud = ses.scenes[0]["clouds"]["lidar_front"].astype(float)
    apex = np.array(ses.truth["scenes"][0]["apex_main"])
    kw = {"head_size": rig["reflector"]["head_size_m"], "edge": rig["reflector"]["edge_m"]}
    ext = extract_reflectors(cloud, offset=rig["reflector"]["offset_m"] if sampling == "grid" else 0.0, **kw)
    assert len(ext.centres) == 3 and ext.method == ["plates"] * 3
    assert sum("line-like" in why for _, why in ext.rejected) == 3  # the three tripods' legs
    err = np.linalg.norm(ext.centres[:, None] - apex[None], axis=2).min(axis=0)
    # float32 clouds: the grid pattern's centroid moved along the fitted boresight is exact; random points: the plates' intersection
    assert err.max() < (2e-5 if sampling == "grid" else 2e-3), err
    # the old rule (centroid moved along the viewing ray) is off by ~offset * 2 sin(turn / 2) for these reflectors
    c = np.array([cl.mean(axis=0) for cl in np.split(trihedral_points(apex[0], -apex[0], 0.25, 8), 1)])
    assert c.shape == (1, 3)
    turn = np.radians(np.abs(ses.truth["scenes"][0]["turn_deg"]))
    assert np.all(reflector_offset(0.25) * 2 * np.sin(turn / 2) > 0.05)


def test_plates_span_two_dimensions_legs_do_not():
    rng = np.random.default_rng(0)
    plates = trihedral_points(np.zeros(3), np.array([1.0, 0.2, 0.1]), 0.25, 8)
    leg = np.linspace(0, 1, 60)[:, None] * np.array([0.3, 0.1, -0.9]) + rng.normal(0, 0.003, (60, 3))
    assert linear_fraction(plates) < 0.1 and linear_fraction(leg) > 0.9
    f = fit_trihedral(plates, edge=0.25)
    assert f is not None and np.linalg.norm(f.apex) < 1e-9 and f.boresight @ np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1]) > 1 - 1e-9
    assert fit_trihedral(np.vstack([leg, leg + [0.2, 0, 0], leg + [0, 0.2, 0]]), edge=0.25) is None


def test_multipath_ghost_split_by_rcs_and_weights():
    rng = np.random.default_rng(2)
    direct = np.array([3.0, 0.5]) + rng.normal(0, 0.02, (10, 2))
    ghost = np.array([3.25, 0.54]) + rng.normal(0, 0.02, (10, 2))  # 25 cm behind, 8 dB weaker: one cluster by distance
    xy = np.vstack([direct, ghost])
    rcs = np.r_[12 + rng.normal(0, 1, 10), 4 + rng.normal(0, 1, 10)]
    m, c = aggregate_frames(xy)
    assert len(m) == 1  # by distance alone the ghost is averaged into the reflector
    m, c, r = aggregate_frames(xy, rcs=rcs)
    k = int(np.argmax(r))
    assert len(m) == 2 and c.tolist() == [10, 10] and np.linalg.norm(m[k] - [3.0, 0.5]) < 0.02
    w = rcs_weights(np.array([12.0, 11.0, 2.0, -6.0, np.nan]))
    assert w[0] == pytest.approx(1.0) and w[3] < 0.02 and w[4] == 1.0


def _ground_wall(rng, n=20000):
    g = np.c_[rng.uniform(-10, 10, (n, 2)), np.zeros(n)]
    wall = np.c_[np.full(n // 2, 8.0), rng.uniform(-8, 8, n // 2), rng.uniform(0, 2.5, n // 2)]
    return np.vstack([g, wall])


def test_lidar_lateral_unobserved_without_reflectors_observed_with():
    rng = np.random.default_rng(5)
    T_main_src = geometry.T_from_xyz_rpy_deg(-0.4, 1.0, 0.5, 0.0, 5.0, 70.0)
    T_v_main = geometry.T_from_xyz_rpy_deg(2.0, 0.0, 1.4, 0.0, 0.0, 0.0)
    world_a, world_b = _ground_wall(rng), _ground_wall(rng)
    tgt = geometry.transform_points(geometry.invert_T(T_v_main), world_a)
    src = geometry.transform_points(geometry.invert_T(T_v_main @ T_main_src), world_b)
    ref = refine_with_reflectors(src, tgt, T_main_src)
    assert 3 * ref.worst_trans[0] > 0.02 and axis_name(ref.worst_trans[1], "main") == "y of main"  # along the wall: refused at 2 cm
    apex_v = np.array([[4.0, 1.0, 1.0], [4.5, -1.2, 1.2], [3.5, 0.2, 0.9]])
    a_main = geometry.transform_points(geometry.invert_T(T_v_main), apex_v)
    a_src = geometry.transform_points(geometry.invert_T(T_v_main @ T_main_src), apex_v) + rng.normal(0, 0.003, (3, 3))
    T0 = T_main_src.copy()
    T0[1, 3] += 0.15  # a guess 15 cm off along the unobserved direction
    ref = refine_with_reflectors(src, tgt, T0, [a_src], [a_main])
    deg, m = geometry.pose_error(ref.T_target_source, T_main_src)
    assert ref.n_reflectors == 3 and 3 * ref.worst_trans[0] < 0.02 and m < 0.01 and deg < 0.2, (deg, m, ref.worst_trans)


@pytest.mark.slow
@pytest.mark.parametrize("family", ["tune", "check"])
def test_feature_sessions_against_the_ideal_fit_never_stored_wrong(family, tmp_path):
    """docs/radar_lidar.md, `python -m benchmarks.radar_lidar features 6`: every radar of both families within 1.2x
    the ideal fit (issue 18), the truth within 3 sigma >= 95 %, the second LiDAR never stored wrong."""
    from benchmarks.radar_lidar import feature_benchmark

    b = feature_benchmark(family, range(100, 106), tmp_path)
    for name, d in b["radars"].items():
        assert d["n"] == 6, name
        assert d["ratio_deg"] <= 1.2 and d["ratio_m"] <= 1.2, (name, d)
    assert b["lidar_stored_wrong"] == 0
    assert (b["lidar_stored_ok"] == 6) if family == "tune" else (b["lidar_refused"] == 6)  # check: a 70 deg FOV sees no reflector
    for _, _, d in b["lidars"]:
        assert d["refused"] is None or "is not observed" in d["refused"]
    assert np.all(b["coverage_3sigma"] >= 0.95), b["coverage_3sigma"]


def test_frame_averages_are_inverse_variance_means():
    """Frames of one cluster 3 dB apart (one RCS class) are averaged with inverse-variance weights 10^(RCS/10) and the
    cluster's RCS is the power mean; a single frame 15 dB weaker than the others (a ghost or clutter 25 cm off) is a
    class of its own, split out instead of averaged in."""
    xy = np.array([[3.0, 0.0], [3.0, 0.0], [3.0, 0.0], [3.25, 0.0]])
    m, c, r = aggregate_frames(xy, rcs=np.array([10.0, 10.0, 10.0, 7.0]))
    w = 10 ** (-0.3)
    assert len(m) == 1 and c.tolist() == [4]
    assert m[0, 0] == pytest.approx(3.0 + 0.25 * w / (3 + w), abs=1e-12)  # arithmetic mean: 3.0625
    assert r[0] == pytest.approx(10 + 10 * np.log10((3 + w) / 4), abs=1e-9)
    m, c, r = aggregate_frames(xy, rcs=np.array([10.0, 10.0, 10.0, -5.0]))
    order = np.argsort(c)
    assert c[order].tolist() == [1, 3]
    assert m[order, 0] == pytest.approx([3.25, 3.0], abs=1e-12)
    assert r[order] == pytest.approx([-5.0, 10.0], abs=1e-9)


def test_rcs_scaled_association_takes_split_frames_drops_ghosts():
    """Two reflectors predicted at known points: a turned reflector's weak frames scattered 0.5 m (its sigma at
    -8 dBsm is 8x a 10 dBsm echo's) are all taken, a strong detection as far off is not, and a detection behind a
    reflector on its ray, 8 dB weaker than the reflector's own (its multipath ghost), is dropped."""
    from radarcal.extrinsics.radar.rig import _associate

    pred = np.array([[3.0, 1.0], [3.0, -1.0]])
    m = np.array([[3.0, 1.02],     # 0: reflector 0 (turned, 0 dBsm)
                  [3.45, 1.15],    # 1: reflector 0's ghost: same ray, farther, 8 dB weaker -> dropped
                  [3.0, -1.45],    # 2: reflector 1, weak frame 45 cm off -> taken (sigma 0.16 m)
                  [2.6, -0.8],     # 3: reflector 1, weak frame 45 cm off the other way -> taken
                  [3.5, -1.0]])    # 4: strong, 50 cm off reflector 1 -> not taken (sigma 2 cm)
    rcs = np.array([0.0, -8.0, -8.0, -8.0, 10.0])
    pairs = _associate(pred, m, rcs, np.ones(5), gate=0.35, sigma_unit=0.02, rcs_ref=10.0)
    assert {tuple(p) for p in pairs.tolist()} == {(0, 0), (1, 2), (1, 3)}


def test_multipath_of_names_the_reflector_on_whose_echo_path_a_detection_lies():
    """A reflector 3 m ahead, 1.1 m up, radar plane 0.5 m: its direct echo and its ground-mirror ghost (slant range
    with dz = 1.6 m) lie on its echo path; a detection 0.5 m across the bearing or 1 m beyond the mirror does not."""
    from radarcal.extrinsics.radar.geometry2d import multipath_of

    q = np.array([[3.0, 0.0], [0.0, 3.0]])
    z = np.array([1.1, 1.1])
    direct, mirror = np.hypot(3.0, 0.6), np.hypot(3.0, 1.6)
    m = np.array([[direct, 0.0], [mirror, 0.02], [mirror, 0.5], [mirror + 1.0, 0.0], [0.0, mirror]])
    assert multipath_of(m, q, z, 0.5, 0.2).tolist() == [0, 0, -1, -1, 1]
    assert multipath_of(m, q, z, 0.5, 0.2, ghost_only=True).tolist() == [-1, 0, -1, -1, 1]  # the direct echo is no ghost
    assert multipath_of(np.zeros((0, 2)), q, z, 0.5, 0.2).shape == (0,)


@pytest.mark.parametrize("seed", range(5))
def test_outlier_rule_keeps_a_far_isolated_reflector_and_finds_a_gross_outlier_behind_it(seed):
    """Five reflectors within 0.5 m of each other and one 2.5 m away, 2 cm noise: the far one's hold-out residual is
    large (the others fix the yaw poorly: high leverage), yet it is no outlier and is kept; a detection 40 cm off
    among the close ones is rejected although the far one's hold-out residual in metres is the largest."""
    from radarcal.extrinsics.radar import Pose2, reject_outliers

    src = np.array([[2.0, 0.0], [2.2, 0.3], [2.4, -0.2], [2.1, 0.1], [2.3, 0.05], [2.5, 2.5]])
    dst = Pose2(np.radians(10.0), np.array([0.3, -0.2])).apply(src) + np.random.default_rng(seed).normal(0, 0.02, src.shape)
    keep, _ = reject_outliers(src, dst, threshold=0.1, k_sigma=3.0)
    assert keep.all()
    dst[1] += [0.4, 0.0]
    keep, why = reject_outliers(src, dst, threshold=0.1, k_sigma=3.0)
    assert keep.tolist() == [True, False, True, True, True, True] and why[0][0] == 1


def test_association_drops_a_much_weaker_detection_beside_a_reflector_even_when_nearer():
    """Tripod-foot clutter 30 cm nearer the radar than a strong reflector echo and 14 dB weaker is within its
    RCS-scaled gate, but one reflector returns one power: only the strong echo is taken."""
    from radarcal.extrinsics.radar.rig import _associate

    pred = np.array([[3.0, 0.0]])
    m = np.array([[3.01, 0.0], [2.7, 0.05]])
    pairs = _associate(pred, m, np.array([8.0, -6.0]), np.array([1.0, 3.0]), gate=0.35, sigma_unit=0.05, rcs_ref=8.0)
    assert pairs.tolist() == [[0, 0]]
    pairs = _associate(pred, m[1:], np.array([-6.0]), np.array([3.0]), gate=0.35, sigma_unit=0.05, rcs_ref=8.0)
    assert pairs.tolist() == [[0, 0]]  # alone, the weak echo is within its gate (sigma 0.17 m)


def test_outlier_rule_does_not_test_a_strong_echo_that_carries_a_parameter_of_the_fit():
    """Two strong echoes (unit weight, 3 cm noise) among three weak ones (weight 0.02: 21 cm): each strong one carries
    more than a parameter's worth of the fit's information (trace of its leverage 1.4), so the others can neither
    predict it nor give a noise scale for it. Over 300 noise draws neither is rejected (without the leverage rule 14
    were, and one such rejection put check seed 300's left radar 13.7 deg off)."""
    from radarcal.extrinsics.radar import Pose2, reject_outliers

    src = np.array([[1.5, 1.0], [2.0, -1.5], [2.5, 2.0], [3.0, 0.3], [1.8, -0.5]])
    w = np.array([0.02, 1.0, 0.02, 1.0, 0.02])
    true = Pose2(np.radians(20.0), np.array([0.3, -0.2]))
    for seed in range(300):
        dst = true.apply(src) + np.random.default_rng(seed).normal(0, 1, src.shape) * (0.03 / np.sqrt(w))[:, None]
        keep, _ = reject_outliers(src, dst, threshold=0.15, k_sigma=3.0, weights=w)
        assert keep[1] and keep[3], seed


def test_a_merged_clutter_cluster_does_not_make_a_single_frame_a_ghost():
    """Three frames: two reflectors seen in each, three clutter sources within 0.1 m that single linkage merges into
    one cluster of 9 detections, and one frame of a turned reflector's weak echo. The 30 % rule counts frames (the
    most-seen cluster's count capped at the median count of the clusters seen more than once: 3, not 9), and the 9
    are cut into their three sources (a source is seen once per frame): the single frame is kept, as itself (at 9 it
    was dropped as a ghost)."""
    rng = np.random.default_rng(0)
    clutter = np.repeat(np.array([[2.5, -1.0], [2.6, -1.05], [2.55, -0.95]]), 3, axis=0)
    xy = np.concatenate([np.array([2.0, 0.0]) + rng.normal(0, 0.01, (3, 2)), np.array([3.0, 1.0]) + rng.normal(0, 0.01, (3, 2)),
                         clutter + rng.normal(0, 0.005, (9, 2)), [[3.6, -0.2]]])
    m, c = aggregate_frames(xy)
    assert sorted(c.tolist()) == [1, 3, 3, 3, 3, 3]  # the merged 9 are cut into their three sources (one per frame each)
    assert m[np.argmin(c)] == pytest.approx([3.6, -0.2], abs=1e-12)
    assert np.sort(np.linalg.norm(m[c == 3][:, None] - np.array([[2.5, -1.0], [2.6, -1.05], [2.55, -0.95]])[None], axis=2).min(axis=0)).max() < 0.02
    m, c = aggregate_frames(  # five frames of two reflectors and a one-frame ghost: still dropped
        np.concatenate([np.repeat([[2.0, 0.0], [3.0, 1.0]], 5, axis=0), [[3.6, -0.2]]]))
    assert c.tolist() == [5, 5]


def test_clean_oracle_keeps_only_reflector_echoes_and_the_excess_names_the_sessions():
    """The benchmark's diagnosis tools: ``only_reflector_echoes`` leaves exactly the detections labelled as a
    reflector's echo, with their labels and sigmas still aligned; ``excess_by_session`` ranks sessions by their share
    of ``sum(ours^2 - ideal^2)``."""
    from benchmarks.radar_lidar import excess_by_session, only_reflector_echoes
    from radarcal.synth.radar import feature_spec, generate_radar_session

    ses = generate_radar_session(feature_spec(600, "check"))
    before = [np.array(t["detection_label"]) for t in ses.truth["scenes"]]
    only_reflector_echoes(ses)
    for sc, tr, lab in zip(ses.scenes, ses.truth["scenes"], before):
        n = int((lab >= 0).sum())
        assert 0 < n < len(lab)  # the session had clutter, ghosts or multipath, and echoes
        assert len(sc["radar"]["radar"]) == len(sc["radar"]["xy"]) == len(sc["radar"]["rcs"]) == len(tr["detection_sigma_m"]) == n
        assert min(tr["detection_label"]) >= 0 and all(v is not None for v in tr["detection_sigma_m"])
    rs = [{"deg": 2.0, "ideal_deg": 1.0}, {"deg": 1.0, "ideal_deg": 1.5}, {"deg": 3.0, "ideal_deg": 1.0}]
    ex = excess_by_session([7, 8, 9], rs)
    assert [s for s, _ in ex] == [9, 7, 8] and [f for _, f in ex] == pytest.approx([8 / 9.75, 3 / 9.75, -1.25 / 9.75])


def test_a_weak_echo_chained_to_tripod_foot_clutter_is_cut_from_it():
    """Three frames (two facing reflectors seen in each): a turned reflector's weak echo scattered ~0.1 m about its
    apex and two static clutter returns at its tripod's feet 0.25-0.3 m away, every RCS within 3 dB (no RCS class
    split), chain into one single-linkage cluster of 9 detections whose mean is ~0.2 m off. A source is seen at most
    once per frame: the crowded cluster is cut into three compact parts, one of which is the echo (its mean within
    0.06 m of the apex; the merged mean was 0.2 m away)."""
    rng = np.random.default_rng(5)
    apex = np.array([2.0, 1.0])
    echo = apex + np.array([[0.08, -0.05], [-0.06, 0.09], [0.02, -0.07]])
    feet = np.repeat(np.array([[2.25, 1.12], [2.22, 0.72]]), 3, axis=0) + rng.normal(0, 0.01, (6, 2))
    facing = np.repeat(np.array([[3.0, -1.0], [2.5, 2.5]]), 3, axis=0) + rng.normal(0, 0.01, (6, 2))
    xy = np.concatenate([echo, feet, facing])
    rcs = np.r_[-7.0, -8.0, -6.5, -6.0, -5.5, -6.2, -7.1, -6.8, -5.9, 8.0, 8.2, 7.9, 9.0, 8.5, 8.8]
    m, c, r = aggregate_frames(xy, rcs=rcs)
    assert sorted(c.tolist()) == [3, 3, 3, 3, 3]
    near = np.argmin(np.linalg.norm(m - apex, axis=1))
    assert np.linalg.norm(m[near] - apex) < 0.06
    merged = np.concatenate([echo, feet])
    w = 10 ** ((rcs[:9] - rcs[:9].max()) / 10)
    assert np.linalg.norm((merged * w[:, None]).sum(0) / w.sum() - apex) > 0.15  # what one cluster of the nine gave


def test_frames_per_source_is_pooled_over_the_session():
    """Three frames per placement. One placement holds a full three-frame source and two sources missed once (two
    detections each): alone its median says 2, which would cut its full source in two. Pooled with the radar's other
    placements (independent layouts, every source seen three times) the count is 3 and that source stays whole."""
    from radarcal.extrinsics.radar import frames_per_source

    rng = np.random.default_rng(1)
    full_a = np.repeat([[2.0, 0.0], [3.0, 1.0], [2.5, -1.5]], 3, axis=0) + rng.normal(0, 0.02, (9, 2))
    full_b = np.repeat([[1.5, 1.0], [3.5, -0.5], [4.0, 2.0], [2.2, -2.5]], 3, axis=0) + rng.normal(0, 0.02, (12, 2))
    missed = np.concatenate([np.repeat([[2.0, 0.5]], 3, axis=0), np.repeat([[3.0, -1.0], [1.2, 2.0]], 2, axis=0)]) + rng.normal(0, 0.02, (7, 2))
    assert frames_per_source([missed]) == 2  # this placement alone
    assert frames_per_source([full_a, full_b, missed]) == 3
    assert frames_per_source([np.array([[1.0, 0.0], [2.0, 0.0]])]) is None  # single frames: nothing repeats
    assert frames_per_source([np.zeros((0, 2)), full_a]) == 3  # a placement where this radar saw nothing
    _, c = aggregate_frames(missed, frames=3)
    assert sorted(c.tolist()) == [2, 2, 3]
    _, c = aggregate_frames(missed, frames=2)  # the placement's own count cuts the full source
    assert sorted(c.tolist()) == [1, 2, 2, 2]

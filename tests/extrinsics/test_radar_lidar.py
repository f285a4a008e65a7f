"""Radar <-> radar / LiDAR <-> radar calibration cores against generated truth and the TU Delft example."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.radar import (
    Pose2,
    board_reflector_centres,
    build_scene_obs,
    calibrate_rig,
    extract_reflectors,
    filter_detections,
    fit_ground_plane,
    fit_rigid_2d,
    leave_one_out,
    procrustes_2d,
    procrustes_floor,
    quantisation_report,
    reject_outliers,
    robust_match_2d,
    slant_predict,
    deslant,
)
from radarcal.synth.radar import RadarRigSpec, RadarSceneSpec, generate_radar_session


def _obs(ses):
    rig = ses.rig
    out = []
    for sc in ses.scenes:
        names = np.array(sc["radar"]["radar"])
        o, _, _ = build_scene_obs(sc["name"], sc["clouds"][rig["main_lidar"]].astype(float), {n: sc["radar"]["xy"][names == n] for n in rig["radars"]},
                                  offset=rig["reflector"]["offset_m"], head_size=rig["reflector"]["head_size_m"])
        out.append(o)
    return out


def _calibrate(ses, **kw):
    rig = ses.rig
    init = {n: geometry.T_from_xyz_rpy_deg(*v["initial_T_main"]) for n, v in rig["radars"].items() if "initial_T_main" in v}
    return calibrate_rig(_obs(ses), list(rig["radars"]), {n: v["mount_height_m"] for n, v in rig["radars"].items()}, reference=rig["reference_radar"],
                         init_T_lidar_radar=init or None, **kw)


def _errors(ses, cal):
    return {n: geometry.pose_error(r.T_lidar_radar, np.array(ses.truth["T_main_sensor"][n])) for n, r in cal.radars.items()}


# --- 2D cores -------------------------------------------------------------------------------------------------------
def test_procrustes_and_nls_exact():
    rng = np.random.default_rng(0)
    src = rng.uniform(-3, 3, (5, 2))
    pose = Pose2(0.7, np.array([1.5, -0.4]))
    dst = pose.apply(src)
    p = procrustes_2d(src, dst)
    assert abs(p.theta - 0.7) < 1e-12 and np.allclose(p.t, pose.t, atol=1e-12)
    f = fit_rigid_2d(src, dst, init=Pose2(0.0, np.zeros(2)))  # NLS from a bad start
    assert abs(f.pose.theta - 0.7) < 1e-9 and np.allclose(f.pose.t, pose.t, atol=1e-9) and f.rms < 1e-9
    z = rng.uniform(0.8, 1.3, 5)
    dst_s = slant_predict(pose.apply(src), z - 0.45)
    np.testing.assert_allclose(deslant(dst_s, z - 0.45), pose.apply(src), atol=1e-12)
    g = fit_rigid_2d(src, dst_s, src_z=z, height=0.45)
    assert abs(g.pose.theta - 0.7) < 1e-9 and np.allclose(g.pose.t, pose.t, atol=1e-9)
    h = fit_rigid_2d(src, dst_s, src_z=z, estimate_height=True, height_init=0.2)
    assert abs(h.height - 0.45) < 1e-6 and abs(h.pose.theta - 0.7) < 1e-8


def test_floor_matches_closed_form():
    src = np.array([[1.0, 2.0], [1.0, -2.0], [3.0, 1.0], [3.0, -1.0]])
    f = procrustes_floor(src, 0.05)
    c = src - src.mean(axis=0)
    assert f["yaw_rad"] == pytest.approx(0.05 / np.sqrt(np.sum(c**2)), rel=1e-6)
    # translation of R src + t at the origin: centroid noise + yaw lever arm
    assert f["translation_m"] == pytest.approx(np.sqrt(2 * 0.05**2 / 4 + f["yaw_rad"] ** 2 * np.sum(src.mean(axis=0) ** 2)), rel=1e-6)


def test_robust_match_with_ghosts_and_no_init():
    rng = np.random.default_rng(3)
    src = np.array([[2.0, 1.0], [3.5, -0.5], [2.5, -1.8], [4.0, 1.5]])
    pose = Pose2(-0.6, np.array([0.4, 0.9]))
    dst = np.vstack([pose.apply(src) + rng.normal(0, 0.01, (4, 2)), [[5.0, 3.0], [1.0, -3.0]]])[[4, 2, 0, 5, 3, 1]]
    src_x = np.vstack([src, [[6.0, -4.0]]])  # a LiDAR clutter cluster
    pairs, p = robust_match_2d(src_x, dst, init=None, gate=0.2)
    truth = {0: 2, 1: 5, 2: 1, 3: 4}
    assert {int(i): int(j) for i, j in pairs} == truth
    assert abs(p.theta + 0.6) < 0.02


def test_ground_plane_and_extraction_exact():
    from radarcal.synth.radar import reflector_offset, trihedral_points

    rng = np.random.default_rng(1)
    T_g_l = geometry.T_from_xyz_rpy_deg(0, 0, 1.4, 2.0, -5.0, 0)  # a tilted LiDAR 1.4 m above the ground
    T_l_g = geometry.invert_T(T_g_l)
    ground = np.c_[rng.uniform(-8, 8, (4000, 2)), np.zeros(4000)]
    apex = np.array([[2.5, 0.8, 1.0], [3.0, -1.0, 1.2]])
    refl = np.vstack([trihedral_points(a, T_g_l[:3, 3] - a, 0.2, 6) for a in apex])  # facing the LiDAR
    far = np.c_[rng.uniform(4.3, 4.6, 300), rng.uniform(-0.2, 0.2, 300), rng.uniform(0.1, 1, 300)]  # a post beyond the 4 m gate
    pts_l = geometry.transform_points(T_l_g, np.vstack([ground, refl, far]))
    g = fit_ground_plane(pts_l)
    np.testing.assert_allclose(g.normal, T_l_g[:3, 2], atol=1e-9)
    assert g.d == pytest.approx(1.4, abs=1e-9)
    ext = extract_reflectors(pts_l, range_gate=4.0, head_size=0.3, offset=reflector_offset(0.2))
    exp = geometry.transform_points(T_l_g, apex)
    assert len(ext.centres) == 2
    got = ext.centres[np.argsort(ext.centres[:, 1])]
    np.testing.assert_allclose(got, exp[np.argsort(exp[:, 1])], atol=1e-9)
    np.testing.assert_allclose(np.sort(ext.heights), [1.0, 1.2], atol=1e-9)
    assert any("range gate" in why for _, why in ext.rejected)


def test_filter_sets_abc():
    # reference-frame detections of three radars: two reflectors seen by >= 2 radars, a ghost seen by one, one outside
    left = np.array([[2.0, 1.0], [3.0, -1.0], [1.0, 4.0]])
    mid = np.array([[2.05, 1.02], [3.02, -0.97], [6.0, 0.0]])
    right = np.array([[3.01, -1.03], [2.5, -4.0]])
    fr = filter_detections([left, mid, right], forward=(0, 5), lateral=(-5, 5), gate=0.2)
    assert fr.counts() == {"A": 7, "B": 5, "C": 2}
    assert set(fr.C.tolist()) == {2, 7}  # the lone left ghost and the right radar's lone detection
    assert sorted(fr.cluster_radars.tolist()) == [1, 1, 2, 3]


def test_quantisation_report():
    q = quantisation_report(np.round(np.random.default_rng(0).uniform(-5, 5, (50, 2)) / 0.2) * 0.2)
    assert q["quantised"] and q["step_m"] == 0.2
    assert not quantisation_report(np.random.default_rng(0).uniform(-5, 5, (50, 2)))["quantised"]


# --- the whole rig on generated sessions -----------------------------------------------------------------------------
def test_noise_free_rig_exact():
    spec = RadarSceneSpec(radar_sigma=0.0, lidar_noise=0.0, init_error=(3.0, 0.1), seed=11)
    ses = generate_radar_session(spec)
    cal = _calibrate(ses)
    for n, (deg, m) in _errors(ses, cal).items():
        assert np.radians(deg) < 1e-6 and m < 1e-6, (n, deg, m)
        assert cal.radars[n].fit.rms < 1e-6
    # patent chain (theta1, a1, b1) radar -> reference radar is exact too
    T_m = np.array(ses.truth["T_vehicle_sensor"]["radar_middle"])
    T_l = np.array(ses.truth["T_vehicle_sensor"]["radar_left"])
    rel = Pose2.from_T(geometry.invert_T(T_m) @ T_l)
    p1 = cal.radars["radar_left"].pairwise_pose_ref
    assert abs(p1.theta - rel.theta) < 1e-3  # pairwise step uses a nominal reflector height for the slant (initialisation)
    assert np.linalg.norm(p1.t - rel.t) < 0.02


def test_noise_free_without_initial_guesses_ransac():
    spec = RadarSceneSpec(radar_sigma=0.0, lidar_noise=0.0, init_error=None, ghost_rate=1.0, p_miss=0.1, seed=4)
    ses = generate_radar_session(spec)
    cal = _calibrate(ses)
    for n, (deg, m) in _errors(ses, cal).items():
        assert np.radians(deg) < 1e-6 and m < 1e-6, (n, deg, m)


def test_slant_model_removes_height_bias():
    # reflectors on one side, 0.6 m above the radars' plane: the planar model is biased, the slant model exact
    apex = [[(1.4, 0.6, 1.1), (2.2, 1.6, 1.1), (3.2, 0.9, 1.1), (2.8, 2.2, 1.1)]]
    spec = RadarSceneSpec(rig=RadarRigSpec(radars={"radar_middle": (2.05, 0.0, 0.50, 0.0)}), n_scenes=1, reflectors_per_scene=4, fixed_apexes=apex,
                          radar_sigma=0.0, lidar_noise=0.0, init_error=None, seed=3)
    ses = generate_radar_session(spec)
    slant = _calibrate(ses, model="slant")
    planar = _calibrate(ses, model="planar")
    T_true = np.array(ses.truth["T_main_sensor"]["radar_middle"])

    def inplane(T):
        dR = T_true[:3, :3].T @ T[:3, :3]
        T_v = np.array(ses.truth["T_vehicle_sensor"]["lidar_front"])
        return abs(np.degrees(np.arctan2(dR[1, 0], dR[0, 0]))), float(np.linalg.norm((T_v @ T)[:2, 3] - (T_v @ T_true)[:2, 3]))

    ys, ts = inplane(slant.radars["radar_middle"].T_lidar_radar)
    yp, tp = inplane(planar.radars["radar_middle"].T_lidar_radar)
    assert np.radians(ys) < 1e-6 and ts < 1e-6
    assert tp > 0.05 and planar.radars["radar_middle"].fit.rms > 0.01  # the height bias the slant model removes
    assert yp > 10 * ys


@pytest.mark.parametrize("offset", [0.2, 0.3])
def test_one_bad_reflector_among_five_rejected(offset):
    # five reflectors in front of the middle radar; every radar return of reflector 0 is displaced (multipath)
    apex = [[(1.5, 1.8, 1.0), (1.8, -1.6, 1.05), (2.6, 0.2, 0.95), (3.3, 1.2, 1.1), (3.2, -1.3, 1.0)]]
    spec = RadarSceneSpec(rig=RadarRigSpec(radars={"radar_middle": (2.05, 0.0, 0.50, 0.0)}), n_scenes=1, reflectors_per_scene=5, fixed_apexes=apex,
                          radar_sigma=0.01, lidar_noise=0.002, bad_reflector_offset=offset, init_error=(3.0, 0.1), seed=8)
    ses = generate_radar_session(spec)
    cal = _calibrate(ses)
    apex_main = np.array(ses.truth["scenes"][0]["apex_main"])
    bad = int(np.argmin(np.linalg.norm(_obs(ses)[0].lidar_centres - apex_main[0], axis=1)))
    r = cal.radars["radar_middle"]
    assert [li for (_, li, _), _ in r.rejected] == [bad]
    assert [p["lidar_index"] for p in r.per_reflector if not p["used"]] == [bad]
    deg, m = _errors(ses, cal)["radar_middle"]
    # what is left is 4 reflectors at sigma = 1 cm: errors of the order of the floor (~0.15 deg / 1 cm)
    assert deg < 0.5 and m < 0.02, (deg, m)
    cal_kept = _calibrate(ses, outlier_threshold=np.inf)  # without rejection the bad reflector biases the fit
    deg2, m2 = _errors(ses, cal_kept)["radar_middle"]
    assert deg2 > 2 * deg or m2 > 2 * m


def test_monte_carlo_within_floor_quick():
    from benchmarks.radar_lidar import monte_carlo

    r = monte_carlo(n_runs=16, sigma=0.05, frames=1, seed0=1000)
    # a short run: loose bound (the 200-run figure is in the slow test and the benchmark)
    assert r["ratio_yaw"] < 1.6 and r["ratio_pos"] < 1.6
    assert r["floor_yaw_deg"] == pytest.approx(0.70, abs=0.02) and r["floor_pos_m"] == pytest.approx(0.0485, abs=0.002)


@pytest.mark.slow
@pytest.mark.parametrize("frames", [1, 100])
def test_monte_carlo_200_runs_within_1p1_floor(frames):
    from benchmarks.radar_lidar import monte_carlo

    r = monte_carlo(n_runs=200, sigma=0.05, frames=frames, seed0=1000)
    assert r["ratio_yaw"] <= 1.1 and r["ratio_pos"] <= 1.1, r


# --- real data: TU Delft example --------------------------------------------------------------------------------------
def test_tudelft_slant_model_and_holdout(shared):
    from radarcal.io.radar import read_tudelft_accumulator, read_tudelft_example

    root = shared("tudelft_msc_example")
    circ, rxy = read_tudelft_example(root / "optimization_example_data")
    c12, r12, _ = read_tudelft_accumulator(root / "accumulator" / "example_data.yaml")
    p, p12 = board_reflector_centres(circ, 0.105), board_reflector_centres(c12, 0.105)
    naive = fit_rigid_2d(p[:, :2], rxy)
    slant = fit_rigid_2d(p[:, :2], rxy, src_z=p[:, 2], estimate_height=True, height_init=0.0)
    # SOURCE.md reference fits: naive 1.97 cm RMS, slant + height 1.19 cm (yaw -90.964 deg, t = (-2.585, 0.192))
    assert naive.rms == pytest.approx(0.0197, abs=0.0005)
    assert slant.rms <= 0.012
    assert np.degrees(slant.pose.theta) == pytest.approx(-90.964, abs=0.4)
    np.testing.assert_allclose(slant.pose.t, [-2.585, 0.192], atol=0.04)
    assert abs(abs(p[:, 2].mean() - slant.height) - 0.40) < 0.03  # only |dz| ~ 0.40 m is identifiable
    # hold-out: the 12 accumulator placements predicted by the 29-placement fit, and a fit on the 12 alone agrees
    q = slant.pose.apply(p12[:, :2])
    hold = np.sqrt(np.mean(np.sum((slant_predict(q, p12[:, 2] - slant.height) - r12) ** 2, axis=1)))
    hold_naive = np.sqrt(np.mean(np.sum((naive.pose.apply(p12[:, :2]) - r12) ** 2, axis=1)))
    assert hold < 0.02 and hold < hold_naive
    g = fit_rigid_2d(p12[:, :2], r12, src_z=p12[:, 2], estimate_height=True, height_init=0.0)
    assert abs(np.degrees(g.pose.theta - slant.pose.theta)) < 0.4 and np.linalg.norm(g.pose.t - slant.pose.t) < 0.04
    loo = leave_one_out(p[:, :2], rxy, src_z=p[:, 2], estimate_height=True, height_init=0.0)
    assert loo["holdout_rms"] < 0.015


def test_tudelft_outlier_files_match_ignore_list(shared):
    import yaml

    from radarcal.io.radar import read_tudelft_example

    root = shared("tudelft_msc_example") / "optimization_example_data"
    circ, rxy = read_tudelft_example(root, "lidar_with_error.csv", "radar_with_error.csv")
    ign = yaml.safe_load((root / "ignored_measurements.yaml").read_text())
    bad = sorted(set(i // 4 for i in ign["lidar1"]) | set(ign["radar1"]))
    p = board_reflector_centres(circ, 0.105)
    pairs, _ = robust_match_2d(p[:, :2], rxy, gate=0.1)
    assert sorted(set(range(29)) - set(pairs[:, 0].tolist())) == bad
    keep, _ = reject_outliers(p[:, :2], rxy, threshold=0.1, src_z=p[:, 2], estimate_height=True, height_init=0.0)
    assert sorted(np.nonzero(~keep)[0].tolist()) == bad
    f = fit_rigid_2d(p[keep, :2], rxy[keep], src_z=p[keep, 2], estimate_height=True, height_init=0.0)
    assert f.rms < 0.013  # the authors report 1.41 cm lidar->radar with the ignore list


def test_joint_refinement_uses_radar_only_reflectors():
    # a fourth reflector 4.6 m ahead: beyond the LiDAR range gate, seen by the radars only -> a free point in the joint fit
    apex = [[(1.6, 1.2, 1.0), (2.4, -1.0, 1.0), (3.2, 0.4, 1.0), (4.6, 0.2, 1.0)], [(1.8, -1.5, 1.0), (2.9, 1.4, 1.0), (3.4, -0.6, 1.0), (4.7, -0.5, 1.0)]]
    spec = RadarSceneSpec(n_scenes=2, reflectors_per_scene=4, fixed_apexes=apex, radar_sigma=0.0, lidar_noise=0.0, init_error=(3.0, 0.1), seed=12)
    ses = generate_radar_session(spec)
    cal = _calibrate(ses, joint=True)
    assert cal.joint["free_points"] >= 2 and cal.joint["rms"] < 1e-6
    for n, (deg, m) in _errors(ses, cal).items():  # float32 clouds: the ground plane is good to ~1e-6 m here
        assert np.radians(deg) < 1e-6 and m < 3e-6, (n, deg, m)
    # with noise the joint solution is at least as close to the truth on average as the LiDAR-only one
    spec = RadarSceneSpec(n_scenes=2, reflectors_per_scene=4, fixed_apexes=apex, radar_sigma=0.03, lidar_noise=0.002, init_error=(3.0, 0.1), seed=13)
    ses = generate_radar_session(spec)
    ej = _errors(ses, _calibrate(ses, joint=True))
    es = _errors(ses, _calibrate(ses, joint=False))
    assert sum(v[0] for v in ej.values()) < 1.5 * sum(v[0] for v in es.values())


def test_unknown_mount_height_estimated():
    spec = RadarSceneSpec(n_scenes=4, radar_sigma=0.0, lidar_noise=0.0, init_error=(3.0, 0.1), seed=15)
    ses = generate_radar_session(spec)
    rig = ses.rig
    heights = {n: v["mount_height_m"] for n, v in rig["radars"].items()}
    heights["radar_right"] = None
    init = {n: geometry.T_from_xyz_rpy_deg(*v["initial_T_main"]) for n, v in rig["radars"].items()}
    cal = calibrate_rig(_obs(ses), list(rig["radars"]), heights, reference="radar_middle", init_T_lidar_radar=init)
    r = cal.radars["radar_right"]
    assert r.mount_height == pytest.approx(ses.truth["radar_mount_height_m"]["radar_right"], abs=1e-5)
    assert any("radar_right" in n and "estimated" in n for n in cal.notes)
    deg, m = _errors(ses, cal)["radar_right"]
    assert deg < 1e-3 and m < 1e-4


def test_scene_checks_and_uncalibratable_radar_noted():
    spec = RadarSceneSpec(n_scenes=2, radar_sigma=0.0, lidar_noise=0.0, ghost_rate=4.0, init_error=(3.0, 0.1), seed=5)
    ses = generate_radar_session(spec)
    obs = _obs(ses)
    for o in obs:
        o.radar_xy["radar_right"] = np.zeros((0, 2))  # this radar saw nothing
    rig = ses.rig
    init = {n: geometry.T_from_xyz_rpy_deg(*v["initial_T_main"]) for n, v in rig["radars"].items()}
    cal = calibrate_rig(obs, list(rig["radars"]), {n: v["mount_height_m"] for n, v in rig["radars"].items()}, reference="radar_middle", init_T_lidar_radar=init)
    assert "radar_right" not in cal.radars and any("radar_right: fewer than 2" in n for n in cal.notes)
    assert any("single-radar detections" in n for n in cal.notes)  # 4 ghosts per radar and frame
    for n, (deg, m) in _errors(ses, cal).items():
        assert np.radians(deg) < 1e-6 and m < 1e-6, (n, deg, m)

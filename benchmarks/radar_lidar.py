"""Radar <-> LiDAR calibration: Monte-Carlo accuracy against the Procrustes (Cramér-Rao) floor, the slant-range bias,
and the TU Delft example (``python -m benchmarks radar_lidar``).

Monte Carlo: one radar (the middle one), N = 4 reflectors at a fixed placement, radar noise sigma per axis, generated
by :mod:`radarcal.synth.radar` and run through the whole pipeline (LiDAR reflector extraction from the synthetic cloud,
ground plane, A/B/C filter, NLS with the slant model). Yaw and radar-position errors are measured against the
generator's truth; the floor is the Cramér-Rao bound of the same model and geometry (for the planar model it is the
Procrustes floor of issue 7: 0.59 deg / 4.9 cm for its geometry; ours is printed next to it).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.extrinsics.radar import (
    Pose2,
    build_scene_obs,
    calibrate_rig,
    fit_rigid_2d,
    procrustes_floor,
)
from radarcal.synth.radar import RadarRigSpec, RadarSceneSpec, generate_radar_session

# N = 4 reflectors (forward, lateral, apex height) relative to the main LiDAR's ground point
MC_APEXES = [[(1.6, 2.4, 1.00), (1.6, -2.4, 1.10), (3.4, 1.0, 0.95), (3.4, -1.0, 1.15)]]
MC_RADAR = {"radar_middle": (2.05, 0.0, 0.50, 0.0)}


def _spec(seed: int, sigma: float, frames: int, model_heights: bool = True, lidar_noise: float = 0.002, **kw) -> RadarSceneSpec:
    rig = RadarRigSpec(radars=dict(MC_RADAR))
    return RadarSceneSpec(rig=rig, n_scenes=1, reflectors_per_scene=4, fixed_apexes=MC_APEXES, radar_sigma=sigma, n_frames=frames, lidar_noise=lidar_noise,
                          init_error=None, seed=seed, **kw)


def run_once(spec: RadarSceneSpec, model: str = "slant") -> dict:
    """Generate, extract, calibrate; errors of the single radar against truth (vehicle frame, in-plane)."""
    ses = generate_radar_session(spec)
    rig = ses.rig
    obs = []
    for sc in ses.scenes:
        names = np.array(sc["radar"]["radar"])
        o, _, _ = build_scene_obs(sc["name"], sc["clouds"][rig["main_lidar"]].astype(float), {n: sc["radar"]["xy"][names == n] for n in rig["radars"]},
                                  offset=rig["reflector"]["offset_m"], head_size=rig["reflector"]["head_size_m"])
        obs.append(o)
    heights = {n: v["mount_height_m"] for n, v in rig["radars"].items()}
    cal = calibrate_rig(obs, list(rig["radars"]), heights, model=model, joint=False, outlier_threshold=np.inf)
    T_v_main = np.array(ses.truth["T_vehicle_sensor"][rig["main_lidar"]])
    out = {}
    for n, res in cal.radars.items():
        T_true = np.array(ses.truth["T_vehicle_sensor"][n])
        T_est = T_v_main @ res.T_lidar_radar
        dR = T_true[:3, :3].T @ T_est[:3, :3]
        out[n] = {"yaw_err": float(np.arctan2(dR[1, 0], dR[0, 0])), "xy_err": T_est[:2, 3] - T_true[:2, 3], "rms": res.fit.rms, "n": res.fit.n}
    return out


def floor_for(spec: RadarSceneSpec, sigma_eff: float, radar: str = "radar_middle", slant: bool = True) -> dict:
    """Cramér-Rao floor of one radar's (yaw, position) for the spec's geometry and an effective per-axis sigma."""
    ses = generate_radar_session(spec)
    T_v_r = np.array(ses.truth["T_vehicle_sensor"][radar])
    apex_v = np.concatenate([np.array(s["apex_vehicle"]) for s in ses.truth["scenes"]])
    # dst = R src + t with src = apex in the vehicle (ground) frame, dst = radar horizontal position
    pose = Pose2.from_T(geometry.invert_T(T_v_r))
    kw = {"src_z": apex_v[:, 2], "height": float(T_v_r[2, 3])} if slant else {}
    f = procrustes_floor(apex_v[:, :2], sigma_eff, pose, **kw)
    return f


def monte_carlo(n_runs: int = 200, sigma: float = 0.05, frames: int = 1, seed0: int = 1000, model: str = "slant") -> dict:
    """RMS yaw / position errors over ``n_runs`` generated sessions and the floor for the same geometry."""
    yaw, pos = [], []
    t0 = time.perf_counter()
    for k in range(n_runs):  # Monte-Carlo runs
        r = run_once(_spec(seed0 + k, sigma, frames), model)["radar_middle"]
        yaw.append(r["yaw_err"])
        pos.append(r["xy_err"])
    yaw = np.array(yaw)
    pos = np.array(pos)
    fl = floor_for(_spec(seed0, sigma, frames), sigma / np.sqrt(frames), slant=model == "slant")
    fl_planar = floor_for(_spec(seed0, sigma, frames), sigma / np.sqrt(frames), slant=False)
    rms_yaw = float(np.sqrt(np.mean(yaw**2)))
    rms_pos = float(np.sqrt(np.mean(np.sum(pos**2, axis=1))))
    return {"n_runs": n_runs, "sigma": sigma, "frames": frames, "model": model, "rms_yaw_deg": np.degrees(rms_yaw), "rms_pos_m": rms_pos,
            "mean_yaw_deg": float(np.degrees(yaw.mean())), "mean_pos_m": pos.mean(axis=0),
            "floor_yaw_deg": np.degrees(fl["yaw_rad"]), "floor_pos_m": fl["inverse_translation_m"],
            "floor_planar_yaw_deg": np.degrees(fl_planar["yaw_rad"]), "floor_planar_pos_m": fl_planar["inverse_translation_m"],
            "ratio_yaw": rms_yaw / fl["yaw_rad"], "ratio_pos": rms_pos / fl["inverse_translation_m"], "seconds": time.perf_counter() - t0}


SLANT_APEXES = [(1.4, 0.6), (2.2, 1.6), (3.2, 0.9), (2.8, 2.2)]  # reflectors on one side of the radar


def slant_bias(height_diff: float = 0.5, model: str = "slant") -> dict:
    """Noise-free: reflectors ``height_diff`` above the radar plane, all on one side; in-plane error of the model."""
    apexes = [[(f, l, 0.5 + height_diff) for f, l in SLANT_APEXES]]
    spec = RadarSceneSpec(rig=RadarRigSpec(radars=dict(MC_RADAR)), n_scenes=1, reflectors_per_scene=4, fixed_apexes=apexes, radar_sigma=0.0, lidar_noise=0.0, init_error=None, seed=7)
    r = run_once(spec, model)["radar_middle"]
    return {"yaw_deg": abs(np.degrees(r["yaw_err"])), "pos_m": float(np.linalg.norm(r["xy_err"])), "rms_m": r["rms"]}


def tudelft(root) -> dict:
    from radarcal.extrinsics.radar import (
        board_reflector_centres,
        leave_one_out,
        slant_predict,
    )
    from radarcal.io.radar import read_tudelft_accumulator, read_tudelft_example

    circ, rxy = read_tudelft_example(root / "optimization_example_data")
    c12, r12, _ = read_tudelft_accumulator(root / "accumulator" / "example_data.yaml")
    p, p12 = board_reflector_centres(circ), board_reflector_centres(c12)
    out = {}
    for name, kw in (("naive 2D (patent)", {}), ("slant + radar height", {"src_z": p[:, 2], "estimate_height": True, "height_init": 0.0})):
        f = fit_rigid_2d(p[:, :2], rxy, **kw)
        q = f.pose.apply(p12[:, :2])
        pred = q if f.height is None else slant_predict(q, p12[:, 2] - f.height)
        hold = float(np.sqrt(np.mean(np.sum((pred - r12) ** 2, axis=1))))
        kw12 = {} if not kw else {"src_z": p12[:, 2], "estimate_height": True, "height_init": 0.0}
        g = fit_rigid_2d(p12[:, :2], r12, **kw12)
        loo = leave_one_out(p[:, :2], rxy, **kw)
        out[name] = {"yaw_deg": np.degrees(f.pose.theta), "t": f.pose.t, "height": f.height, "rms_m": f.rms, "holdout12_rms_m": hold,
                     "fit12_yaw_deg": np.degrees(g.pose.theta), "fit12_t": g.pose.t, "loo_rms_m": loo["holdout_rms"], "sigma_yaw_deg": np.degrees(f.sigma["theta"])}
    return out


def main(argv: list[str]) -> int:
    if argv and argv[0] == "features":  # python -m benchmarks.radar_lidar features [n_seeds [first_seed [clean]]]
        import tempfile

        k = int(argv[1]) if len(argv) > 1 else 6
        s0 = int(argv[2]) if len(argv) > 2 else 100
        clean = len(argv) > 3 and argv[3] == "clean"
        with tempfile.TemporaryDirectory() as tmp:
            for fam in ("tune", "check"):
                print_feature_benchmark(feature_benchmark(fam, range(s0, s0 + k), Path(tmp), clean=clean))
        return 0
    n = int(argv[0]) if argv else 200
    print(f"Monte Carlo: 1 radar, N = 4 reflectors, full pipeline (synthetic cloud -> extraction -> NLS), {n} runs each")
    print(f"{'sigma':>6} {'frames':>6} {'model':>6} | {'RMS yaw':>9} {'floor':>8} {'ratio':>6} | {'RMS pos':>8} {'floor':>8} {'ratio':>6} | {'planar floor':>17} | {'s':>5}")
    for sigma, frames, model in ((0.05, 1, "slant"), (0.05, 100, "slant"), (0.05, 100, "planar")):
        r = monte_carlo(n if model == "slant" else max(n // 4, 10), sigma, frames, model=model)
        print(f"{sigma:6.3f} {frames:6d} {r['model']:>6} | {r['rms_yaw_deg']:8.4f}° {r['floor_yaw_deg']:7.4f}° {r['ratio_yaw']:6.3f} | {100 * r['rms_pos_m']:6.3f}cm {100 * r['floor_pos_m']:6.3f}cm {r['ratio_pos']:6.3f} | "
              f"{r['floor_planar_yaw_deg']:.4f}° {100 * r['floor_planar_pos_m']:.3f}cm | {r['seconds']:5.1f}")
    print("(issue 7's floor for its geometry: 0.59° / 4.9 cm at 1 frame, 0.059° / 0.49 cm at 100 frames; the planar row is the")
    print(" patent's model on the same data: reflectors 0.45-0.65 m above the radar plane bias it beyond the floor)")
    print("\nSlant-range bias, noise-free, four reflectors on one side, dz above the radar plane:")
    for dz in (0.25, 0.5):
        for model in ("planar", "slant"):
            b = slant_bias(dz, model)
            print(f"  dz={dz:.2f} m {model:>6}: yaw error {b['yaw_deg']:.4f}°, position error {100 * b['pos_m']:.3f} cm, residual {100 * b['rms_m']:.3f} cm")
    root = Path(__file__).resolve().parents[1].parent / "shared" / "datasets" / "tudelft_msc_example"
    if root.is_dir():
        print("\nTU Delft example (29 placements; hold-out = the 12 accumulator placements):")
        for name, d in tudelft(root).items():
            print(f"  {name:>22}: yaw {d['yaw_deg']:.3f}°, t=({d['t'][0]:.3f}, {d['t'][1]:.3f}) m, RMS {100 * d['rms_m']:.2f} cm, LOO {100 * d['loo_rms_m']:.2f} cm, "
                  f"hold-out {100 * d['holdout12_rms_m']:.2f} cm; fit on the 12: yaw {d['fit12_yaw_deg']:.3f}°, t=({d['fit12_t'][0]:.3f}, {d['fit12_t'][1]:.3f})"
                  + (f", radar height {d['height']:.3f} m" if d["height"] is not None else ""))
    oc = Path(__file__).resolve().parents[1].parent / "shared" / "datasets" / "opencalib_lidar2lidar_0001"
    if oc.is_dir():
        print("\nOpenCalib lidar2lidar/0001: left/right -> top from initial_extrinsic.txt (fitness / inlier RMSE at 0.3 m):")
        for name, d in lidar_lidar(oc).items():
            print(f"  {name:>22}: fitness {d['f0']:.3f} -> {d['f1']:.3f}, RMSE {d['r0']:.3f} -> {d['r1']:.3f} m, tilt fixed by the ground {d['tilt']:.1f}°, "
                  f"rpy {d['rpy'][0]:.2f} {d['rpy'][1]:.2f} {d['rpy'][2]:.2f}°, xyz {d['xyz'][0]:.3f} {d['xyz'][1]:.3f} {d['xyz'][2]:.3f} m, {d['s']:.1f} s")
    return 0


def lidar_lidar(root) -> dict:
    from radarcal.extrinsics.radar.lidar_lidar import register_lidar
    from radarcal.io import read_cloud

    top = read_cloud(root / "top.pcd").points.astype(float)
    guess = {"left": (-0.06763169358385032, 0.6257701373941718, -0.35145357319239473, 0, 0, 90), "right": (-0.0001307057033816915, -0.4632752877792159, -0.46602840121078765, 0, 0, -90)}
    out = {}
    for name, g in guess.items():
        src = read_cloud(root / f"{name}.pcd").points.astype(float)
        for method in ("gicp", "point_to_plane"):
            t0 = time.perf_counter()
            r = register_lidar(src, top, geometry.T_from_xyz_rpy_deg(*g), method=method)
            xr = geometry.T_to_xyz_rpy_deg(r.T_target_source)
            out[f"{name} ({method})"] = {"method": method, "f0": r.initial_fitness, "f1": r.fitness, "r0": r.initial_rmse, "r1": r.inlier_rmse,
                                         "tilt": (r.prealign or {}).get("tilt_fixed_deg", float("nan")), "rpy": xr[3:], "xyz": xr[:3], "s": time.perf_counter() - t0}
    return out


# --- sessions with the held-out features (issue 18), through the code path of the command -------------------------
def ideal_fit_error(ses, radar: str, range_gate: float = 4.0) -> tuple[float, float, float, float]:
    """(yaw deg, position m) error of the ideal least-squares fit on the same detections: every detection of a true
    reflector (generator labels) that the LiDAR can see (within its ``range_gate``, horizontally) against its true
    apex, slant model at the true mounting height, weighted by the generator's own per-detection sigma (the best
    linear unbiased estimate); then its own Cramer-Rao sigma of yaw (deg) and position (m, radar in the ground frame)
    from those sigmas -- what any estimator's error is on average for this session, while the ideal's error is one
    draw of it."""
    T_v_r = np.array(ses.truth["T_vehicle_sensor"][radar])
    main_xy = np.array(ses.truth["T_vehicle_sensor"][ses.truth["main_lidar"]])[:2, 3]
    src, dst, z, w = [], [], [], []
    for sc, tr in zip(ses.scenes, ses.truth["scenes"]):
        names = np.array(sc["radar"]["radar"])
        lab = np.array(tr["detection_label"])
        sig = np.array([np.nan if v is None else v for v in tr["detection_sigma_m"]])
        ap = np.array(tr["apex_vehicle"])
        seen = np.linalg.norm(ap[:, :2] - main_xy, axis=1) <= range_gate
        sel = (names == radar) & (lab >= 0)
        sel[sel] = seen[lab[sel]]
        src.append(ap[lab[sel], :2]), z.append(ap[lab[sel], 2]), dst.append(sc["radar"]["xy"][sel]), w.append(1 / sig[sel] ** 2)
    src, dst, z, w = map(np.concatenate, (src, dst, z, w))
    f = fit_rigid_2d(src, dst, src_z=z, height=ses.truth["radar_mount_height_m"][radar], weights=w, sigma_meas=1.0)  # w = 1 / sigma^2
    p, t = f.pose.inverse(), Pose2.from_T(T_v_r)
    crb = f.inverse_sigma()
    return (float(np.degrees(abs((p.theta - t.theta + np.pi) % (2 * np.pi) - np.pi))), float(np.linalg.norm(p.t - t.t)), float(np.degrees(crb["theta"])),
            float(np.hypot(crb["a"], crb["b"])))


def only_reflector_echoes(ses) -> None:
    """Diagnosis only: drop, in place, every radar detection the generator labels as no reflector's echo (clutter,
    ghosts, multipath), so that a run measures the solver on exactly the detections the ideal fit may use."""
    for sc, tr in zip(ses.scenes, ses.truth["scenes"]):
        keep = np.array(tr["detection_label"]) >= 0
        r = sc["radar"]
        sc["radar"] = {"radar": [n for n, k in zip(r["radar"], keep) if k], "xy": r["xy"][keep], "rcs": r["rcs"][keep], "velocity": r["velocity"][keep]}
        tr["detection_label"] = [v for v, k in zip(tr["detection_label"], keep) if k]
        tr["detection_sigma_m"] = [v for v, k in zip(tr["detection_sigma_m"], keep) if k]


def feature_session(seed: int, family: str, workdir: Path, clean: bool = False) -> dict:
    """Generate one session of ``family`` (:func:`radarcal.synth.radar.feature_spec`), write it, read it back and run
    ``calibrate`` as ``radarcal radar-lidar`` does; errors against truth, the ideal fit, sigma z-scores, LiDARs.
    ``clean``: the generator's non-reflector detections removed first (:func:`only_reflector_echoes`)."""
    from radarcal.extrinsics.radar.session import calibrate
    from radarcal.io.radar import read_radar_session
    from radarcal.synth.radar import feature_spec, write_radar_session

    ses = generate_radar_session(feature_spec(seed, family))
    if clean:
        only_reflector_echoes(ses)
    folder = write_radar_session(ses, workdir / f"{family}_{seed}")
    t0 = time.perf_counter()
    res = calibrate(read_radar_session(folder))
    out = {"seed": seed, "family": family, "radars": {}, "lidars": {}, "refusals": res.refusals, "s": time.perf_counter() - t0}
    T_G_main = geometry.invert_T(res.cal.T_lidar_G)
    for r, rr in res.cal.radars.items():
        T_true = np.array(ses.truth["T_main_sensor"][r])
        deg, m = geometry.pose_error(rr.T_lidar_radar, T_true)
        ideg, im, cdeg, cm = ideal_fit_error(ses, r)
        true_G = Pose2.from_T(T_G_main @ T_true)
        err = np.array([(rr.pose_G.theta - true_G.theta + np.pi) % (2 * np.pi) - np.pi, *(rr.pose_G.t - true_G.t)])
        sig = np.array([rr.sigma_G["theta"], rr.sigma_G["a"], rr.sigma_G["b"]])
        out["radars"][r] = {"deg": deg, "m": m, "ideal_deg": ideg, "ideal_m": im, "crb_deg": cdeg, "crb_m": cm, "z": err / sig}
    for n, d in res.lidars.items():
        deg, m = geometry.pose_error(d["T"], np.array(ses.truth["T_main_sensor"][n]))
        out["lidars"][n] = {"deg": deg, "m": m, "refused": d["refused"], "reflector_pairs": d["refinement"].n_reflectors}
    return out


def feature_benchmark(family: str, seeds, workdir: Path, clean: bool = False) -> dict:
    """Pooled over ``seeds``: per radar the RMS error and that of the ideal fit (ratio), the sessions that carry the
    excess, the share of sigma z-scores within 3, and every second-LiDAR outcome (stored within 0.2 deg / 2 cm,
    refused, or stored wrong). ``clean``: see :func:`feature_session`."""
    runs = [feature_session(s, family, workdir, clean) for s in seeds]
    radars = {}
    for name in runs[0]["radars"]:
        rs = [r["radars"][name] for r in runs if name in r["radars"]]
        def rms(k, rs=rs):
            return float(np.sqrt(np.mean([x[k] ** 2 for x in rs])))

        def per_crb(k, c, rs=rs):  # RMS of the error in units of the session's own Cramer-Rao sigma (~1 for an efficient estimator)
            return float(np.sqrt(np.mean([(x[k] / x[c]) ** 2 for x in rs])))

        radars[name] = {"n": len(rs), "rms_deg": rms("deg"), "ideal_rms_deg": rms("ideal_deg"), "rms_m": rms("m"), "ideal_rms_m": rms("ideal_m"),
                        "ratio_deg": rms("deg") / rms("ideal_deg"), "ratio_m": rms("m") / rms("ideal_m"),
                        "crb_units_deg": per_crb("deg", "crb_deg"), "ideal_crb_units_deg": per_crb("ideal_deg", "crb_deg"),
                        "crb_units_m": per_crb("m", "crb_m"), "ideal_crb_units_m": per_crb("ideal_m", "crb_m"),
                        "excess_deg": excess_by_session([r["seed"] for r in runs if name in r["radars"]], rs, "deg"),
                        "excess_m": excess_by_session([r["seed"] for r in runs if name in r["radars"]], rs, "m")}
    z = np.array([x["z"] for r in runs for x in r["radars"].values()])
    lid = [(r["seed"], n, d) for r in runs for n, d in r["lidars"].items()]
    return {"family": family, "clean": clean, "runs": runs, "radars": radars, "coverage_3sigma": (np.abs(z) <= 3).mean(axis=0) if len(z) else np.zeros(3),
            "lidar_stored_ok": sum(1 for _, _, d in lid if not d["refused"] and d["deg"] <= 0.2 and d["m"] <= 0.02),
            "lidar_refused": sum(1 for _, _, d in lid if d["refused"]), "lidar_stored_wrong": sum(1 for _, _, d in lid if not d["refused"] and (d["deg"] > 0.2 or d["m"] > 0.02)),
            "lidars": lid}


def excess_by_session(seeds: list, rs: list, key: str = "deg") -> list:
    """(seed, share) of the squared error ``key`` (``"deg"`` yaw, ``"m"`` position) beyond the ideal fit's,
    ``sum(ours^2 - ideal^2)``, largest first: which sessions carry a ratio above 1 (shares of sessions where ours is
    the better one are negative)."""
    ex = np.array([x[key] ** 2 - x[f"ideal_{key}"] ** 2 for x in rs])
    total = float(ex.sum())
    order = np.argsort(-ex)
    return [(int(seeds[i]), float(ex[i] / total) if total > 0 else 0.0) for i in order]


def print_feature_benchmark(b: dict) -> None:
    print(f"\nfamily {b['family']!r}{' (clean: reflector echoes only, by the labels)' if b.get('clean') else ''}: {len(b['runs'])} sessions, seeds {b['runs'][0]['seed']}-{b['runs'][-1]['seed']} (tripod legs, turned reflectors, low-RCS clutter, multipath, ground-and-wall, 2nd LiDAR yawed 70 deg)")
    print(f"  {'radar':>13} | {'RMS yaw':>8} {'ideal':>7} {'ratio':>5} | {'RMS pos':>8} {'ideal':>7} {'ratio':>5} | error / ideal's CRB sigma: yaw (ideal), pos (ideal)")
    for n, d in b["radars"].items():
        print(f"  {n:>13} | {d['rms_deg']:7.3f}° {d['ideal_rms_deg']:6.3f}° {d['ratio_deg']:5.2f} | {100 * d['rms_m']:6.2f}cm {100 * d['ideal_rms_m']:5.2f}cm {d['ratio_m']:5.2f} | "
              f"{d['crb_units_deg']:.2f} ({d['ideal_crb_units_deg']:.2f}), {d['crb_units_m']:.2f} ({d['ideal_crb_units_m']:.2f})")
    for n, d in b["radars"].items():
        if d["ratio_deg"] > 1.2 or d["ratio_m"] > 1.2:
            top = {k: ", ".join(f"{s} {100 * f:.0f} %" for s, f in d[f"excess_{k}"][:4]) for k in ("deg", "m")}
            print(f"  {n}: sessions carrying the excess (share of sum(ours^2 - ideal^2)): yaw {top['deg']}; position {top['m']}")
    c = b["coverage_3sigma"]
    print(f"  truth within 3 sigma: yaw {100 * c[0]:.0f} %, x {100 * c[1]:.0f} %, y {100 * c[2]:.0f} % (ground frame)")
    print(f"  second LiDAR: {b['lidar_stored_ok']} stored within 0.2 deg / 2 cm, {b['lidar_refused']} refused, {b['lidar_stored_wrong']} stored wrong")
    for seed, n, d in b["lidars"]:
        print(f"    seed {seed} {n}: {d['deg']:.3f} deg / {100 * d['m']:.2f} cm, {d['reflector_pairs']} reflector pairs" + (f" -- refused: {d['refused']}" if d["refused"] else " -- stored"))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

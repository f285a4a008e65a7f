"""LiDAR-camera extrinsics: accuracy on generated scenes, convergence basin, run time, real data sets.

Run: ``PYTHONPATH=$PWD python -m benchmarks lidar_camera`` (about 5-8 minutes on 2 cores); sections can be
chosen: ``python -m benchmarks.lidar_camera synth basin time mlcc mlcc-joint mlcc-dense opencalib``.
Peer figure in the same process: the edge score (mean capped distance of projected LiDAR edge samples to the
nearest Canny edge) of the shipped reference extrinsic vs ours, on the same edges.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "datasets"


def _synth(seed, deg, m, duration=4.0, **kw):
    from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene

    return render_lidar_camera_scene(LidarCameraSceneParams(seed=seed, duration_s=duration, init_deg=deg, init_m=m, **kw))


def _run(scene_list, T_init, intensity=True, **opts):
    """Edges + refinement as ``radarcal lidar-camera --refine`` does it (plane edges, plus reflectivity edges unless
    ``intensity=False``)."""
    from radarcal.extrinsics.edges import image_edges, lidar_edges, lidar_intensity_edges, merge_edges
    from radarcal.extrinsics.refine import EdgeScene, RefineOptions, refine_edges

    t0 = time.perf_counter()
    scenes = [EdgeScene(s.camera, merge_edges(lidar_edges(s.points), lidar_intensity_edges(s.points, s.intensity) if intensity else None), image_edges(s.image))
              for s in scene_list]
    t1 = time.perf_counter()
    r = refine_edges(scenes, T_init, RefineOptions(**opts))
    return r, t1 - t0, time.perf_counter() - t1


def synth_accuracy(seeds=(1, 2, 3, 4, 5, 6)) -> None:
    from radarcal import geometry

    print("\n-- generated scenes (Mid-70-like rosette 4 s, 2 cm noise, 1280x1024 radtan camera) --")
    print(f"{'edges':>17} {'seed':>4} {'start':>10} {'rot err deg':>11} {'trans err cm':>12} {'verdict':>14} {'matches':>7} {'s':>5}  ok(<0.1deg,<2cm)")
    for deg, m, intensity in ((3.0, 0.10, False), (3.0, 0.10, True), (6.0, 0.20, False), (6.0, 0.20, True)):
        ok_n = 0
        label = "planes+reflectivity" if intensity else "planes"
        for seed in seeds:
            s = _synth(seed, deg, m)
            r, te, tr = _run([s], s.T_init, intensity=intensity)
            e_deg, e_m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
            ok = e_deg < 0.1 and e_m < 0.02
            ok_n += ok
            verdict = "converged" if r.converged else "NOT converged"
            print(f"{label:>17} {seed:>4} {f'{deg:g}deg/{m * 100:g}cm':>10} {e_deg:11.3f} {e_m * 100:12.2f} {verdict:>14} {r.n_matches:7d} {te + tr:5.1f}  {'yes' if ok else 'no'}"
                  + ("  (claimed converged but wrong)" if r.converged and not ok else ""))
        print(f"  -> {label}: {ok_n}/{len(seeds)} within 0.1 deg / 2 cm from {deg:g} deg / {m * 100:g} cm")
    # multi-scene joint refinement: two scenes of the same rig
    s1, s2 = _synth(5, 3.0, 0.1), None
    from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene

    s2 = render_lidar_camera_scene(LidarCameraSceneParams(seed=6, duration_s=4.0, T_cam_lidar=s1.T_cam_lidar))
    for name, lst in (("seed 5 alone", [s1]), ("seed 6 alone", [s2]), ("5 + 6 joint", [s1, s2])):
        r, te, tr = _run(lst, s1.T_init, intensity=False)
        e = geometry.pose_error(r.T_cam_lidar, s1.T_cam_lidar)
        print(f"  multi-scene (planes only) {name:>13}: {e[0]:.3f} deg / {e[1] * 100:.2f} cm, {'converged' if r.converged else 'NOT converged'}, {te + tr:.1f} s")


def basin(seeds=(1, 2, 3, 4, 5, 6), starts=(1, 2, 4, 6, 8), trials=1) -> None:
    from radarcal import geometry

    print("\n-- convergence basin, plane + reflectivity edges (rotation error at start, translation 5 cm; success = < 0.2 deg and < 3 cm) --")
    scenes = {seed: _synth(seed, 3.0, 0.1) for seed in seeds}
    from radarcal.extrinsics.edges import image_edges, lidar_edges, lidar_intensity_edges, merge_edges
    from radarcal.extrinsics.refine import EdgeScene, RefineOptions, refine_edges

    prepared = {seed: EdgeScene(s.camera, merge_edges(lidar_edges(s.points), lidar_intensity_edges(s.points, s.intensity)), image_edges(s.image)) for seed, s in scenes.items()}
    print(f"{'start deg':>9} {'success':>8} {'no-search success':>18} {'mean s':>7}")
    for deg in starts:
        ok = ok_ns = n = 0
        tt = 0.0
        for seed, s in scenes.items():
            for k in range(trials):
                T0 = geometry.perturb_T(s.T_cam_lidar, deg, 0.05, np.random.default_rng(100 * seed + k))
                t0 = time.perf_counter()
                r = refine_edges([prepared[seed]], T0, RefineOptions(coarse_search_deg=max(6.0, deg + 2)))
                tt += time.perf_counter() - t0
                r2 = refine_edges([prepared[seed]], T0, RefineOptions(coarse_search_deg=0))
                e = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
                e2 = geometry.pose_error(r2.T_cam_lidar, s.T_cam_lidar)
                ok += e[0] < 0.2 and e[1] < 0.03
                ok_ns += e2[0] < 0.2 and e2[1] < 0.03
                n += 1
        print(f"{deg:9g} {ok:>4}/{n:<3} {ok_ns:>14}/{n:<3} {tt / n:7.1f}")


def timing() -> None:
    print("\n-- time: 1 M-point rosette cloud (10 s) + one 1280x1024 image --")
    from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene

    t0 = time.perf_counter()
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=1, duration_s=10.0))
    t_render = time.perf_counter() - t0
    print(f"  synth render: {len(s.points)} points hit of 1,000,000 rays + 1280x1024 image at 2x2 supersampling: {t_render:.1f} s (goal < 30 s)")
    from radarcal import geometry

    r, te, tr = _run([s], s.T_init)
    e = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    print(f"  edges {te:.1f} s + refine {tr:.1f} s = {te + tr:.1f} s (goal < 60 s); result {e[0]:.3f} deg / {e[1] * 100:.2f} cm, {r.message}")


def _opencalib_camera(folder: Path):

    d = json.loads((folder / "center_camera-intrinsic.json").read_text())["center_camera-intrinsic"]["param"]
    K = np.array(d["cam_K"]["data"], float)
    dist = np.array(d["cam_dist"]["data"], float).ravel()
    T = np.array(json.loads((folder / "top_center_lidar-to-center_camera-extrinsic.json").read_text())["top_center_lidar-to-center_camera-extrinsic"]["param"]["sensor_calib"]["data"], float)
    return K, dist, T


def real_mlcc(pairs=(0, 2, 4, 8)) -> None:
    from radarcal import geometry
    from radarcal.extrinsics.edges import edge_score, image_edges, lidar_edges
    from radarcal.extrinsics.refine import EdgeScene, RefineOptions, refine_edges
    from radarcal.io import import_camera, read_cloud, read_image

    D = SHARED / "mlcc_livox_mid100_scene2"
    if not D.is_dir():
        print("\n-- mlcc: data set absent, skipped --")
        return
    print("\n-- mlcc_livox_mid100_scene2: from the reference perturbed 3 deg / 10 cm (prior sigma 0.3 m) --")
    meta = json.loads((D / "calib/pairs_T_cam_lidar.json").read_text())["pairs"]
    print(f"{'pair':>4} {'cloud':>22} {'image':>18} {'edges':>6} {'ref score':>9} {'ours':>6} {'vs ref deg':>10} {'cm':>6} {'verdict':>14}")
    for k in pairs:
        p = meta[k]
        cam, _ = import_camera(D / p["intrinsics"])
        T_ref = np.array(p["T_cam_lidar"])
        cloud = read_cloud(D / p["cloud"])
        le = lidar_edges(cloud.points, voxel=0.5, min_points=8, max_range=60)
        sc = EdgeScene(cam, le, image_edges(read_image(D / p["image"])))
        T0 = geometry.perturb_T(T_ref, 3.0, 0.10, np.random.default_rng(k))
        r = refine_edges([sc], T0, RefineOptions(translation_prior_m=0.3))
        e = geometry.pose_error(r.T_cam_lidar, T_ref)
        s_ref = edge_score(cam, T_ref, le, sc.image)[0]
        print(f"{k:>4} {p['cloud']:>22} {p['image']:>18} {len(le.points):6d} {s_ref:9.2f} {r.score_after:6.2f} {e[0]:10.3f} {e[1] * 100:6.1f} {'converged' if r.converged else 'NOT converged':>14}")


def mlcc_chained_pairs(pairs, D: Path = SHARED / "mlcc_livox_mid100_scene2"):
    """mlcc pairs of one camera as one problem: they do not share one ``T_cam_lidar`` (different heads / poses) but
    share ``T_cam_avia``; with the data set's own LiDAR chain C_k = inv(T_ref_0) @ T_ref_k every cloud k moves into
    pair 0's LiDAR frame and pair 0's ``T_cam_lidar`` is the one unknown (T_k = T_0 @ C_k).
    Returns (T_ref_0, [(camera, cloud points as read (float, own frame), image, C_k)])."""
    from radarcal.io import import_camera, read_cloud, read_image

    meta = json.loads((D / "calib/pairs_T_cam_lidar.json").read_text())["pairs"]
    T0_ref = np.array(meta[pairs[0]]["T_cam_lidar"])
    out = []
    for k in pairs:
        p = meta[k]
        cam, _ = import_camera(D / p["intrinsics"])
        out.append((cam, read_cloud(D / p["cloud"]).points.astype(float), read_image(D / p["image"]), np.linalg.inv(T0_ref) @ np.array(p["T_cam_lidar"])))
    return T0_ref, out


def real_mlcc_joint(pairs=(0, 2, 4, 8), seeds=(0, 1, 2)) -> None:
    """All left-camera pairs refined jointly. They do not share one ``T_cam_lidar`` (different heads / poses), but
    they share ``T_left_avia``: with the data set's own LiDAR chain C_k = inv(T_ref_0) @ T_ref_k every cloud k is
    moved into pair 0's LiDAR frame, so ``T_cam_lidar`` of pair 0 is the one unknown (T_k = T_0 @ C_k). Errors are
    reported for pair 0's transform; a perturbation in the camera frame is shared by all pairs."""
    from radarcal import geometry
    from radarcal.extrinsics.edges import LidarEdges, edge_score, image_edges, lidar_edges
    from radarcal.extrinsics.refine import EdgeScene, RefineOptions, refine_edges

    if not (SHARED / "mlcc_livox_mid100_scene2").is_dir():
        print("\n-- mlcc joint: data set absent, skipped --")
        return
    T0_ref, loaded = mlcc_chained_pairs(pairs)
    scenes = []
    for cam, P, img, C in loaded:
        le = lidar_edges(P, voxel=0.5, min_points=8, max_range=60)
        le = LidarEdges(le.points @ C[:3, :3].T + C[:3, 3], le.dirs @ C[:3, :3].T)
        scenes.append(EdgeScene(cam, le, image_edges(img)))
    s_ref = np.mean([edge_score(sc.camera, T0_ref, sc.lidar, sc.image)[0] for sc in scenes])
    print(f"\n-- mlcc joint refinement of pairs {list(pairs)} (one shared unknown via the LiDAR chain), from the reference perturbed 3 deg / 10 cm --")
    for seed in seeds:
        t0 = time.perf_counter()
        r = refine_edges(scenes, geometry.perturb_T(T0_ref, 3.0, 0.10, np.random.default_rng(seed)), RefineOptions(translation_prior_m=0.3))
        e = geometry.pose_error(r.T_cam_lidar, T0_ref)
        ours = np.mean([edge_score(sc.camera, r.T_cam_lidar, sc.lidar, sc.image)[0] for sc in scenes])
        print(f"  start seed {seed}: {e[0]:.3f} deg / {e[1] * 100:.1f} cm from the reference; edge score ref {s_ref:.2f} px, ours {ours:.2f} px; "
              f"{'converged' if r.converged else 'NOT converged'} ({time.perf_counter() - t0:.1f} s)")


def _opencalib_txt(path: Path):
    """K, D, T_cam_lidar of a Calib-Anything ``calib.txt`` (K: 9 numbers, D: 4, T: 12 row-major)."""
    d = {}
    for line in path.read_text().splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            d[k.strip()] = np.array(v.split(), float)
    T = np.eye(4)
    T[:3, :4] = d["T"].reshape(3, 4)
    return d["K"].reshape(3, 3), d["D"], T


OPENCALIB_SCENES = {"auto": (("auto", "calib.png", "calib.pcd"),), "manual": (("manual", "0.png", "0.pcd"),),
                    "calibanything 1+2": (("calibanything_1", "calib.jpg", "calib.pcd"), ("calibanything_2", "calib.jpg", "calib.pcd"))}
# the configurations compared: (label, LiDAR edges, image edges, RefineOptions as the CLI builds them)
OPENCALIB_CONFIGS = {
    "depth 6-DoF": ("depth", dict(method="canny"), dict(translation_prior_m=0.3, coarse_search_deg=2.0, coarse_step_deg=0.5)),  # as measured before
    "intensity rot-only": ("intensity", dict(method="canny", min_length=20),
                           dict(translation_prior_m=0.3, coarse_search_deg=3.0, fix_translation=True, stability_m=0.0, min_matches=20, min_match_fraction=0.2)),
}


def opencalib_prepare(name: str, kind: str, image_kw: dict):
    """EdgeScenes of one opencalib entry (joint entries share K, D, T) plus the yardstick edge sets (intensity edges
    vs Canny >= 20 px, depth edges vs Canny >= 40 px: the same for reference and result) and the reference T."""
    from radarcal.camera import Camera
    from radarcal.extrinsics.edges import crop_to_camera, image_edges, lidar_scan_edges
    from radarcal.extrinsics.refine import EdgeScene
    from radarcal.io import read_cloud, read_image

    D = SHARED / "opencalib_road_64beam"
    scenes, yard = [], []
    for folder, img_name, cloud_name in OPENCALIB_SCENES[name]:
        K, dist, T_ref = _opencalib_camera(D / folder) if (D / folder / "center_camera-intrinsic.json").is_file() else _opencalib_txt(D / folder / "calib.txt")
        img = read_image(D / folder / img_name)
        cam = Camera((img.shape[1], img.shape[0]), K, dist)
        c = read_cloud(D / folder / cloud_name)
        view = crop_to_camera(c.points, cam, T_ref, margin=0.3)  # generous: the starts are <= 2 deg (~4 % of the width) off
        pts, inten, ring = c.points[view], c.intensity[view], None if c.ring is None else c.ring[view]
        scenes.append(EdgeScene(cam, lidar_scan_edges(pts, inten, ring, kind), image_edges(img, **image_kw)))
        yard.append((cam, lidar_scan_edges(pts, inten, ring, "intensity"), image_edges(img, method="canny", min_length=20),
                     lidar_scan_edges(pts, None, None, "depth"), image_edges(img, method="canny")))
    return scenes, yard, T_ref


def opencalib_yardstick(yard, T) -> tuple[float, float]:
    """(intensity-edge score, depth-edge score) in px at ``T``, sample-weighted over the scenes of one entry."""
    from radarcal.extrinsics.edges import edge_score

    out = []
    for which in (0, 1):
        vals = [edge_score(cam, T, le_i if which == 0 else le_d, ie_i if which == 0 else ie_d) for cam, le_i, ie_i, le_d, ie_d in yard]
        out.append(float(sum(v * n for v, n in vals) / max(1, sum(n for _, n in vals))))
    return out[0], out[1]


def opencalib_runs(names=tuple(OPENCALIB_SCENES), configs=tuple(OPENCALIB_CONFIGS), starts=((0.0, 0.0), (1.0, 0.05), (2.0, 0.10)), seeds=(1, 2, 3)) -> list[dict]:
    """Refinements from the shipped reference and from it perturbed (deg, m) with ``seeds``; one dict per run."""
    from radarcal import geometry
    from radarcal.extrinsics.refine import RefineOptions, refine_edges

    rows = []
    for name in names:
        for cfg in configs:
            kind, image_kw, opts = OPENCALIB_CONFIGS[cfg]
            scenes, yard, T_ref = opencalib_prepare(name, kind, image_kw)
            s_ref = opencalib_yardstick(yard, T_ref)
            for deg, m in starts:
                for seed in (seeds if deg > 0 else (0,)):
                    T0 = geometry.perturb_T(T_ref, deg, m, np.random.default_rng(seed)) if deg > 0 else T_ref
                    t0 = time.perf_counter()
                    r = refine_edges(scenes, T0, RefineOptions(**opts))
                    e = geometry.pose_error(r.T_cam_lidar, T_ref)
                    rows.append({"scene": name, "config": cfg, "start_deg": deg, "start_m": m, "seed": seed, "rot_deg": e[0], "trans_m": e[1],
                                 "score_ref": s_ref, "score_result": opencalib_yardstick(yard, r.T_cam_lidar), "score_start": opencalib_yardstick(yard, T0),
                                 "converged": r.converged, "message": r.message, "n_matches": r.n_matches, "match_fraction": r.observability.get("match_fraction", 0.0),
                                 "edges": int(sum(len(sc.lidar.points) for sc in scenes)), "seconds": time.perf_counter() - t0})
    return rows


def real_opencalib() -> None:
    if not (SHARED / "opencalib_road_64beam").is_dir():
        print("\n-- opencalib: data set absent, skipped --")
        return
    print("\n-- opencalib_road_64beam (single 64-beam sweeps cropped to the view; calibanything 1+2 refined jointly, one shared T):"
          " from the shipped reference and from it perturbed 1 deg / 5 cm and 2 deg / 10 cm (seeds 1-3) --")
    print("   yardstick (same edges for reference and result): int = intensity edges vs Canny >= 20 px, depth = depth edges vs Canny >= 40 px;"
          " a claim is WRONG when 'converged' lands > 0.5 deg from the reference (itself good to a few tenths of a degree)")
    print(f"{'scene':>17} {'config':>18} {'start':>9} {'vs ref deg':>10} {'cm':>5} {'int ref':>7} {'int res':>7} {'dep ref':>7} {'dep res':>7} {'match%':>6} {'verdict':>13} {'s':>4}")
    rows = opencalib_runs()
    for r in rows:
        start = "ref" if r["start_deg"] == 0 else f"{r['start_deg']:g}/{r['start_m'] * 100:g} s{r['seed']}"
        wrong = r["converged"] and r["rot_deg"] > 0.5
        print(f"{r['scene']:>17} {r['config']:>18} {start:>9} {r['rot_deg']:10.3f} {r['trans_m'] * 100:5.1f} {r['score_ref'][0]:7.2f} {r['score_result'][0]:7.2f} "
              f"{r['score_ref'][1]:7.2f} {r['score_result'][1]:7.2f} {100 * r['match_fraction']:6.0f} {'converged' if r['converged'] else 'NOT conv.':>13} {r['seconds']:4.0f}"
              + ("  WRONG CLAIM" if wrong else ""))
    print("  summary (perturbed starts):")
    for name in OPENCALIB_SCENES:
        for cfg in OPENCALIB_CONFIGS:
            sel = [r for r in rows if r["scene"] == name and r["config"] == cfg and r["start_deg"] > 0]
            if not sel:
                continue
            rot = np.array([r["rot_deg"] for r in sel])
            no_worse = sum(r["score_result"][0] <= r["score_ref"][0] + 0.05 for r in sel)
            conv = [r for r in sel if r["converged"]]
            print(f"   {name:>17} {cfg:>18}: median {np.median(rot):.2f} deg (max {rot.max():.2f}) from the reference, {int((rot <= 0.5).sum())}/{len(sel)} within 0.5 deg; "
                  f"int score no worse than ref {no_worse}/{len(sel)}; converged {len(conv)}/{len(sel)}, wrong claims {sum(r['rot_deg'] > 0.5 for r in conv)}")


def _mlcc_dense_scenes(pairs):
    """Dense scenes of the given pairs, every cloud moved into the first pair's LiDAR frame with the data set's own
    chain (C_k = inv(T_ref_0) @ T_ref_k, see :func:`real_mlcc_joint`), plus the sparse method's edges as the
    common yardstick."""
    from radarcal.extrinsics.dense import DenseScene, image_energy
    from radarcal.extrinsics.edges import LidarEdges, image_edges, lidar_edges

    T0_ref, loaded = mlcc_chained_pairs(pairs)
    scenes, yard = [], []
    for cam, P, img, C in loaded:
        scenes.append(DenseScene(cam, P[np.linalg.norm(P, axis=1) < 80] @ C[:3, :3].T + C[:3, 3], image_energy(img), origin=C[:3, 3]))
        le = lidar_edges(P, voxel=0.5, min_points=8, max_range=60)
        yard.append((cam, LidarEdges(le.points @ C[:3, :3].T + C[:3, 3], le.dirs @ C[:3, :3].T), image_edges(img)))
    return T0_ref, scenes, yard


def real_mlcc_dense(seeds=(0, 1, 2)) -> dict:
    """Dense edge correlation (``radarcal.extrinsics.dense``), the six left pairs jointly and the six right pairs
    jointly (a second, independent unknown), from the reference perturbed 3 deg / 10 cm. Yardstick for "no worse
    than the reference": ``edges.edge_score`` (plane-intersection samples vs LSD, px, lower = better) on the same
    edges. Consistency: the left-right relative pose of our two independent results vs the reference's."""
    from radarcal import geometry
    from radarcal.extrinsics.dense import refine_dense
    from radarcal.extrinsics.edges import edge_score

    if not (SHARED / "mlcc_livox_mid100_scene2").is_dir():
        print("\n-- mlcc dense: data set absent, skipped --")
        return {}
    print("\n-- mlcc dense edge correlation (6 pairs jointly per camera via the LiDAR chain), from the reference perturbed 3 deg / 10 cm --")
    print(f"{'camera':>6} {'seed':>4} {'deg':>6} {'cm':>5} {'d rot about cam x,y,z (deg)':>28} {'d t (cm)':>18} {'edge score ref/ours px':>22} {'restart spread':>15} "
          f"{'score drop % at 5 cm x/y/z':>26} {'verdict':>14} {'s':>4} goal")
    out = {}
    for cam_name, pairs in (("left", (0, 2, 4, 6, 8, 10)), ("right", (1, 3, 5, 7, 9, 11))):
        T_ref, scenes, yard = _mlcc_dense_scenes(pairs)

        def ys(T):
            return float(np.mean([edge_score(c, T, le, ie)[0] for c, le, ie in yard]))

        s_ref = ys(T_ref)
        for seed in seeds:
            t0 = time.perf_counter()
            r = refine_dense(scenes, geometry.perturb_T(T_ref, 3.0, 0.10, np.random.default_rng(seed)))
            e = geometry.pose_error(r.T_cam_lidar, T_ref)
            d = geometry.T_to_rotvec(r.T_cam_lidar @ np.linalg.inv(T_ref))
            ours = ys(r.T_cam_lidar)
            goal = e[0] < 0.5 and e[1] < 0.05 and ours <= s_ref
            out[(cam_name, seed)] = (r.T_cam_lidar, T_ref, e, ours, s_ref, r.converged)
            print(f"{cam_name:>6} {seed:>4} {e[0]:6.3f} {e[1] * 100:5.1f} {np.array2string(np.degrees(d[:3]), precision=3, sign='+'):>28} "
                  f"{np.array2string((r.T_cam_lidar[:3, 3] - T_ref[:3, 3]) * 100, precision=1, sign='+'):>18} {s_ref:10.2f} / {ours:5.2f}      "
                  f"{r.spread_deg:5.2f} deg {r.spread_m * 100:4.1f} cm {' / '.join(f'{100 * v:.2f}' for v in r.translation_drops.values()):>26} "
                  f"{'converged' if r.converged else 'NOT converged':>14} {time.perf_counter() - t0:4.0f} {'met' if goal else 'not met'}")
            if not r.converged:
                print(f"         {r.message}")
    for seed in seeds:
        if ("left", seed) in out and ("right", seed) in out:
            (TL, TLr, *_), (TR, TRr, *_) = out[("left", seed)], out[("right", seed)]
            e = geometry.pose_error(TR @ np.linalg.inv(TL), TRr @ np.linalg.inv(TLr))
            print(f"  seed {seed}: left-right relative pose from our two independent solves vs the reference's: {e[0]:.3f} deg / {e[1] * 100:.1f} cm")
    return out


# ---------------------------------------------------------------------------------------------------------------
# verdict calibration: false refusals / false acceptances over many scenes of two independent families
# /out/ is git-ignored; "_v2": records with the depth profile (checks["depth_profile"], issue #16 item 10 job 3), so
# that earlier runs (lidar_camera_verdict.jsonl, without it) are not mixed in
VERDICT_CACHE = Path(__file__).resolve().parents[1] / "out" / "lidar_camera_verdict_v2.jsonl"
VERDICT_GOOD = (0.1, 0.02)  # a result within 0.1 deg and 2 cm of the truth must be accepted (<= 10 % refusals)
VERDICT_BAD = (0.2, 0.05)  # a result beyond 0.2 deg or 5 cm must never be called converged


def verdict_scene(family: str, seed: int):
    """One scene of a family, 3 deg / 10 cm off: ``old`` = radarcal.synth.lidar_camera (rosette 1.5 s, 1280x1024),
    ``family2`` = radarcal.synth.lidar_camera_family2 (its own layouts, patterns, cameras; 1 s)."""
    if family == "old":
        return _synth(seed, 3.0, 0.10, duration=1.5)
    from radarcal.synth.lidar_camera_family2 import Family2Params, render_family2_scene

    return render_family2_scene(Family2Params(seed=seed, duration_s=1.0, init_deg=3.0, init_m=0.10))


def _verdict_edge_scenes(scene, methods=("lsd",)) -> dict:
    """The scene's LiDAR edges (crop to the camera, plane + reflectivity edges) with image edges (>= 40 px) of each
    method, as ``radarcal lidar-camera --refine`` builds them: {method: [EdgeScene]}."""
    from radarcal.extrinsics.edges import crop_to_camera, image_edges, lidar_edges, lidar_intensity_edges, merge_edges
    from radarcal.extrinsics.refine import EdgeScene

    view = crop_to_camera(scene.points, scene.camera, scene.T_init, margin=0.3)
    pts = scene.points[view]
    le = merge_edges(lidar_edges(pts, voxel=0.5, max_range=60.0), lidar_intensity_edges(pts, scene.intensity[view], max_range=60.0))
    return {m: [EdgeScene(scene.camera, le, image_edges(scene.image, min_length=40, method=m))] for m in methods}


def verdict_run(scene, image_edges: str = "lsd", **opts):
    """Edges + refinement exactly as ``radarcal lidar-camera --refine [--image-edges auto]`` runs them (translation
    prior 0.3 m). Returns (result, the edge scenes it was refined on, options)."""
    from radarcal.extrinsics.refine import RefineOptions, refine_edges, refine_edges_choosing

    o = RefineOptions(**{"coarse_search_deg": 6.0, "translation_prior_m": 0.3, **opts})
    if image_edges == "auto":
        cand = _verdict_edge_scenes(scene, ("lsd", "lsd+canny", "canny"))
        chosen, results, _ = refine_edges_choosing(cand, cand.pop("canny"), scene.T_init, o)
        return results[chosen], cand[chosen], o
    scenes = _verdict_edge_scenes(scene, (image_edges,))[image_edges]
    return refine_edges(scenes, scene.T_init, o), scenes, o


def _verdict_cache(image_edges: str) -> Path:
    """The sweep's cache: one per image-edge method (records are keyed by family and seed)."""
    return VERDICT_CACHE if image_edges == "lsd" else VERDICT_CACHE.with_name(f"{VERDICT_CACHE.stem}_{image_edges.replace('+', '_')}.jsonl")


EDGES_CACHE = VERDICT_CACHE.with_name("lidar_camera_edges_choice.jsonl")


def edges_choice(families=("family2", "old"), n: int = 30, first: int = 0) -> dict:
    """Accuracy of LSD image edges (the default) vs ``--image-edges auto`` (LSD and LSD+Canny refined, the pose with
    the lower alignment cost on Canny edges kept), fast runs (no bootstrap, no stability restarts: the verdict is
    not measured here). Resumable (one JSON line per family/seed in ``EDGES_CACHE``)."""
    from radarcal import geometry
    from radarcal.extrinsics.refine import RefineOptions, refine_edges_choosing

    o = RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3, bootstrap=0, stability_checks=0)
    done = {}
    if EDGES_CACHE.exists():
        done = {(r["family"], r["seed"]): r for r in map(json.loads, EDGES_CACHE.read_text().splitlines())}
    good = lambda e: e[0] <= VERDICT_GOOD[0] and e[1] <= VERDICT_GOOD[1]  # noqa: E731
    bad = lambda e: e[0] > VERDICT_BAD[0] or e[1] > VERDICT_BAD[1]  # noqa: E731
    rows = {}
    for fam in families:
        for seed in range(first, first + n):
            if (fam, seed) not in done:
                t0 = time.perf_counter()
                s = verdict_scene(fam, seed)
                cand = _verdict_edge_scenes(s, ("lsd", "lsd+canny", "canny"))
                referee = cand.pop("canny")
                best, results, costs = refine_edges_choosing(cand, referee, s.T_init, o)  # results["lsd"] is the default's run
                errs = {m: geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar) for m, r in results.items()}
                rec = {"family": fam, "seed": seed, "layout": s.params.get("layout", "structured"), "lidar": s.params.get("lidar"), "chosen": best, "referee_cost": costs,
                       "err": {m: list(e) for m, e in errs.items()}, "seconds": time.perf_counter() - t0}
                EDGES_CACHE.parent.mkdir(parents=True, exist_ok=True)
                with EDGES_CACHE.open("a") as f:
                    f.write(json.dumps(rec) + "\n")
                done[(fam, seed)] = rec
            r = done[(fam, seed)]
            e_l, e_c = r["err"]["lsd"], r["err"][r["chosen"]]
            print(f"  {fam:>8} {seed:>3} {r['layout']:>10} {str(r['lidar']):>8}  lsd {e_l[0]:6.3f} deg {e_l[1] * 100:5.1f} cm   auto ({r['chosen']:>9}) {e_c[0]:6.3f} deg {e_c[1] * 100:5.1f} cm", flush=True)
            row = rows.setdefault(fam, {"scenes": 0, "lsd_good": 0, "auto_good": 0, "lsd_bad": 0, "auto_bad": 0})
            row["scenes"] += 1
            row["lsd_good"] += good(e_l)
            row["auto_good"] += good(e_c)
            row["lsd_bad"] += bad(e_l)
            row["auto_bad"] += bad(e_c)
    print("| family | scenes | within 0.1 deg / 2 cm: lsd / auto | beyond 0.2 deg / 5 cm: lsd / auto |\n|---|---|---|---|")
    for fam, r in rows.items():
        print(f"| {fam} seeds {first}-{first + n - 1} | {r['scenes']} | {r['lsd_good']} / {r['auto_good']} | {r['lsd_bad']} / {r['auto_bad']} |")
    return rows


def _error_params(T_est, T_true) -> np.ndarray:
    """The error in the refinement's own parameters: T_est = exp(x) T_true, x = (rotation vector rad, translation m)."""
    from radarcal import geometry

    dT = T_est @ np.linalg.inv(T_true)
    return np.concatenate([geometry.R_to_rotvec(dT[:3, :3]), dT[:3, 3]])


def verdict_sweep(families=("family2", "old"), seeds=range(30), cache: Path = VERDICT_CACHE, image_edges: str = "lsd") -> list[dict]:
    """Run (or reuse from ``cache``, one JSON line per family/seed) the refinement on every scene; the records
    hold the truth errors and the checks the verdict is decided on (``RefineResult.checks``)."""
    from radarcal import geometry
    from radarcal.extrinsics.refine import paired_cost_increase

    cache.parent.mkdir(parents=True, exist_ok=True)
    done: dict = {}

    def reload():  # several sweeps may share the cache (one JSON line per scene, appended)
        if cache.exists():
            for line in cache.read_text().splitlines():
                if line.strip():
                    r = json.loads(line)
                    done[(r["family"], r["seed"])] = r

    out = []
    for fam in families:
        for seed in seeds:
            reload()
            if (fam, seed) not in done:
                t0 = time.perf_counter()
                s = verdict_scene(fam, seed)
                res, edge_scenes, o = verdict_run(s, image_edges)
                e_deg, e_m = geometry.pose_error(res.T_cam_lidar, s.T_cam_lidar)
                truth_vs_result = paired_cost_increase(edge_scenes, res.T_cam_lidar, s.T_cam_lidar, o)  # diagnosis only: (cost ratio, t) of the truth
                rec = {"family": fam, "seed": seed, "layout": s.params.get("layout", "structured"), "lidar": s.params.get("lidar"), "err_deg": e_deg, "err_m": e_m,
                       "err_params": _error_params(res.T_cam_lidar, s.T_cam_lidar).tolist(), "converged": res.converged, "message": res.message,
                       "checks": res.checks, "truth_vs_result": list(truth_vs_result), "seconds": time.perf_counter() - t0}
                with cache.open("a") as f:
                    f.write(json.dumps(rec) + "\n")
                done[(fam, seed)] = rec
                print(f"  {fam} seed {seed}: {e_deg:.3f} deg / {e_m * 100:.2f} cm, {'converged' if res.converged else 'refused'} ({rec['seconds']:.0f} s)", flush=True)
            out.append(done[(fam, seed)])
    return out


def _good_by(records: list[dict], key: str) -> dict:
    """{value of ``key``: (scenes, within 0.1 deg / 2 cm)}."""
    out: dict = {}
    for r in records:
        n, g = out.get(r.get(key) or "?", (0, 0))
        out[r.get(key) or "?"] = (n + 1, g + (r["err_deg"] <= VERDICT_GOOD[0] and r["err_m"] <= VERDICT_GOOD[1]))
    return out


def verdict_table(records: list[dict], options=None) -> dict:
    """False-refusal / false-acceptance table of ``edge_verdict`` (re-applied to the stored checks) per family."""
    from radarcal.extrinsics.refine import RefineOptions, edge_verdict, sigma_for_verdict

    o = options or RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3)
    rows = {}
    for fam in dict.fromkeys(r["family"] for r in records):
        rs = [r for r in records if r["family"] == fam]
        good = [r for r in rs if r["err_deg"] <= VERDICT_GOOD[0] and r["err_m"] <= VERDICT_GOOD[1]]
        bad = [r for r in rs if r["err_deg"] > VERDICT_BAD[0] or r["err_m"] > VERDICT_BAD[1]]
        acc = {id(r): edge_verdict(r["checks"], o)[0] for r in rs}
        covered = []
        for r in rs:  # honest sigma: every translation axis within 3 sigma of the truth
            sig = sigma_for_verdict(r["checks"], o)
            covered.append(bool(np.all(np.abs(np.asarray(r["err_params"])[3:]) <= 3 * sig[3:] + 1e-9)))
        rest = [c for r, c in zip(rs, covered) if not (r["err_deg"] <= VERDICT_GOOD[0] and r["err_m"] <= VERDICT_GOOD[1])]
        # "before": records with the sector jackknife (cache v2) are re-judged without it (the jackknife does not change
        # the result, only the sigma); older records keep the verdict the run printed (the standard-deviation bootstrap)
        prev = {id(r): edge_verdict({k: v for k, v in r["checks"].items() if k != "sector_jackknife"}, o)[0] if "sector_jackknife" in r["checks"] else r["converged"]
                for r in rs}
        prev_fr, prev_fa = sum(not prev[id(r)] for r in good), sum(prev[id(r)] for r in bad)
        acc_cov = [c for r, c in zip(rs, covered) if acc[id(r)]]
        by_lidar, by_layout = _good_by(rs, "lidar"), _good_by(rs, "layout")
        rows[fam] = {"scenes": len(rs), "good": len(good), "bad": len(bad), "middle": len(rs) - len(good) - len(bad), "prev_false_refusals": prev_fr,
                     "prev_false_accepts": prev_fa, "accepted_covered": sum(acc_cov), "by_lidar": by_lidar, "by_layout": by_layout,
                     "false_refusals": sum(not acc[id(r)] for r in good), "false_accepts": sum(acc[id(r)] for r in bad),
                     "accepted": sum(acc.values()), "rest_covered": sum(rest), "rest": len(rest), "all_covered": sum(covered)}
    return rows


def verdict_report(families=("family2", "old"), n: int = 30, cached_only: bool = False, first: int = 0, image_edges: str = "lsd") -> dict:
    """Runs the sweep (resumable: scenes already in the cache are not re-run) and prints the table; with
    ``cached_only`` only the cached scenes are tabulated (``verdict-table``)."""
    cache = _verdict_cache(image_edges)
    print(f"\n-- verdict calibration: up to {n} scenes per family (seeds {first}-{first + n - 1}) from 3 deg / 10 cm (CLI defaults, --image-edges {image_edges}; cache {cache}) --")
    if cached_only:
        recs = [json.loads(x) for x in cache.read_text().splitlines() if x.strip()] if cache.exists() else []
        recs = sorted({(r["family"], r["seed"]): r for r in recs if r["family"] in families and first <= r["seed"] < first + n}.values(), key=lambda r: (families.index(r["family"]), r["seed"]))
    else:
        recs = verdict_sweep(families, range(first, first + n), cache, image_edges)
    from radarcal.extrinsics.refine import RefineOptions, edge_verdict

    rows = verdict_table(recs)
    print(f"| family | scenes | within {VERDICT_GOOD[0]:g} deg / {VERDICT_GOOD[1] * 100:g} cm | refused of those (false refusals) | beyond {VERDICT_BAD[0]:g} deg / {VERDICT_BAD[1] * 100:g} cm | "
          f"\"converged\" of those (false acceptances) | in between | accepted | translation within 3 sigma (all / rest) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for fam, r in rows.items():
        print(f"| {fam} | {r['scenes']} | {r['good']} ({100 * r['good'] / max(r['scenes'], 1):.0f} %) | {r['false_refusals']} ({100 * r['false_refusals'] / max(r['good'], 1):.0f} %); before: {r['prev_false_refusals']} | "
              f"{r['bad']} | {r['false_accepts']}; before: {r['prev_false_accepts']} | {r['middle']} | {r['accepted']} (sigma covers {r['accepted_covered']}) | {r['all_covered']}/{r['scenes']} / {r['rest_covered']}/{r['rest']} |")
    for what in ("lidar", "layout"):
        print(f"within 0.1 deg / 2 cm by {what}: " + "; ".join(f"{fam}: " + ", ".join(f"{k} {g}/{n}" for k, (n, g) in sorted(r['by_' + what].items())) for fam, r in rows.items()))
    for rec in recs:
        print(f"  {rec['family']:>8} {rec['seed']:>3} {rec['layout']:>10} {str(rec['lidar']):>8} {rec['err_deg']:7.3f} deg {rec['err_m'] * 100:6.2f} cm  "
              f"{'converged' if edge_verdict(rec['checks'], RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3))[0] else 'refused':>9}  {rec['seconds']:.0f} s")
    return rows


SECTIONS = {"synth": synth_accuracy, "basin": basin, "time": timing, "mlcc": real_mlcc, "mlcc-joint": real_mlcc_joint, "mlcc-dense": real_mlcc_dense, "opencalib": real_opencalib, "verdict": verdict_report, "verdict-table": lambda: verdict_report(cached_only=True)}


def _verdict_args(argv: list[str]) -> dict:
    """``seeds=100-129``, ``families=family2,old`` and ``edges=auto`` after ``verdict`` / ``verdict-table`` (a fresh
    seed range for a held-out figure: the scenes looked at while tuning were seeds 0-29)."""
    kw = {}
    for a in argv:
        k, _, v = a.partition("=")
        if k == "seeds":
            lo, _, hi = v.partition("-")
            kw["first"], kw["n"] = int(lo), int(hi or lo) - int(lo) + 1
        elif k == "families":
            kw["families"] = tuple(v.split(","))
        elif k == "edges":
            kw["image_edges"] = v
    return kw


def main(argv: list[str]) -> int:
    if argv and argv[0] == "edges-choice":
        edges_choice(**_verdict_args(argv[1:]))
        return 0
    if argv and argv[0] in ("verdict", "verdict-table"):
        verdict_report(cached_only=argv[0] == "verdict-table", **_verdict_args(argv[1:]))
        return 0
    names = argv or list(SECTIONS)
    for n in names:
        SECTIONS[n]()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

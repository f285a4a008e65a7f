"""The edge-refinement verdict against ground truth on small scenes of both families (the old structured scene and
the independent family2): a right result (within 0.1 deg / 2 cm of the truth) is called converged, a wrong one is
refused. The false-refusal / false-acceptance rates over 30+ scenes per family are a benchmark
(``python -m benchmarks.lidar_camera verdict``, docs/lidar_camera.md)."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.edges import crop_to_camera, image_edges, lidar_edges, lidar_intensity_edges, merge_edges
from radarcal.extrinsics.refine import EdgeScene, RefineOptions, edge_verdict, match_edges, refine_edges, sector_jackknife, sigma_for_verdict
from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene
from radarcal.synth.lidar_camera_family2 import Family2Params, render_family2_scene


def _edge_scene(cam, image, points, intensity, T_init):
    view = crop_to_camera(points, cam, T_init, margin=0.3)
    pts = points[view]
    le = merge_edges(lidar_edges(pts, voxel=0.5, max_range=60.0), lidar_intensity_edges(pts, intensity[view], max_range=60.0))
    return EdgeScene(cam, le, image_edges(image, min_length=40))


def _refine(sc, T_init):
    return refine_edges([sc], T_init, RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3))  # the CLI defaults


# each run is 30-60 s on an idle 2-core machine (the verdict's restarts are most of it): slow
@pytest.mark.slow
@pytest.mark.parametrize("family,seed", [("family2", 0), ("old", 0)])
def test_right_result_is_accepted(family, seed):
    # the sweep's scenes (benchmarks.lidar_camera.verdict_scene): family2 seed 0 is a corridor seen by the Avia-like
    # pattern and a 640x512 camera; old seed 0 the structured scene, rosette 1.5 s
    if family == "old":
        s = render_lidar_camera_scene(LidarCameraSceneParams(seed=seed, duration_s=1.5, init_deg=3.0, init_m=0.10))
    else:
        s = render_family2_scene(Family2Params(seed=seed, duration_s=1.0))
    r = _refine(_edge_scene(s.camera, s.image, s.points, s.intensity, s.T_init), s.T_init)
    e_deg, e_m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert e_deg < 0.1 and e_m < 0.02, (e_deg, e_m, r.message)
    assert r.converged, r.message
    # the reported sigma covers the truth (3 sigma per translation axis, in the refinement's parameters)
    dT = r.T_cam_lidar @ np.linalg.inv(s.T_cam_lidar)
    assert np.all(np.abs(dT[:3, 3]) <= 3 * r.sigma_bootstrap[3:])
    assert np.allclose(r.sigma_bootstrap, sigma_for_verdict(r.checks, RefineOptions()))
    assert edge_verdict(r.checks, RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3))[0] == r.converged


@pytest.mark.slow
def test_wrong_result_is_refused():
    # family2 seed 2 (a parking lot, Avia-like): the refinement lands in a wrong minimum; the verdict must say so
    s = render_family2_scene(Family2Params(seed=2, duration_s=1.0))
    r = _refine(_edge_scene(s.camera, s.image, s.points, s.intensity, s.T_init), s.T_init)
    e_deg, e_m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert not r.converged or (e_deg <= 0.2 and e_m <= 0.05), (e_deg, e_m, r.message)
    if e_deg > 0.2 or e_m > 0.05:
        assert r.message.startswith("did not converge")


@pytest.mark.slow
def test_mismatched_image_is_refused():
    # the image of one field and the cloud of another: no extrinsic aligns them, whatever comes out is wrong
    a = render_family2_scene(Family2Params(seed=1, layout="field", lidar="horizon", duration_s=0.5, resolution="640x512"))
    b = render_family2_scene(Family2Params(seed=4, layout="field", lidar="horizon", duration_s=0.5, resolution="640x512"))
    r = _refine(_edge_scene(b.camera, b.image, a.points, a.intensity, b.T_init), b.T_init)
    assert not r.converged, r.message
    assert r.message.startswith("did not converge")


@pytest.mark.slow
def test_image_edges_choice_rescues_a_wrong_lsd_minimum():
    # family2 seed 3 (a corridor, Horizon-like, 640x512; a tuning seed of docs/lidar_camera.md): LSD misses the
    # low-contrast edges and the refinement ends ~0.9 deg / 13 cm off; refined with LSD+Canny it is right, and the
    # Canny alignment cost must pick that one (fast options: the choice, not the verdict, is tested here)
    from radarcal.extrinsics.refine import refine_edges_choosing

    s = render_family2_scene(Family2Params(seed=3, duration_s=1.0))
    sc = _edge_scene(s.camera, s.image, s.points, s.intensity, s.T_init)
    cand = {m: [EdgeScene(s.camera, sc.lidar, image_edges(s.image, min_length=40, method=m))] for m in ("lsd", "lsd+canny")}
    referee = [EdgeScene(s.camera, sc.lidar, image_edges(s.image, min_length=40, method="canny"))]
    o = RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3, bootstrap=0, stability_checks=0)
    chosen, results, costs = refine_edges_choosing(cand, referee, s.T_init, o)
    errs = {m: geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar) for m, r in results.items()}
    assert errs["lsd"][0] > 0.5 or errs["lsd"][1] > 0.05, errs  # the case the choice is for (LSD alone is wrong)
    assert chosen == "lsd+canny" and costs["lsd+canny"] < costs["lsd"], (chosen, costs)
    assert errs[chosen][0] < 0.1 and errs[chosen][1] < 0.04, errs


def _passing_checks(**kw) -> dict:
    """Checks of a result every other part of the verdict accepts (a tight bootstrap, all restarts back)."""
    rng = np.random.default_rng(0)
    boot = rng.normal(0.0, 1.0, (40, 6)) * np.array([np.radians(0.01)] * 3 + [0.003] * 3)
    return {"sigma_bootstrap": boot.std(0).tolist(), "bootstrap_samples": boot.tolist(), "sigma_jacobian": [1e-5] * 6, "centre_move_m": 0.1,
            "converged_stage": True, "stable": True, "valley_settled": True, "match_fraction": 0.6, "n_matches": 800, "rms_px": 0.8,
            "score_before": 5.0, "score_after": 1.0, "moved_deg": 3.0, "moved_m": 0.1, "restarts": [], **kw}


def test_verdict_refuses_a_result_one_image_region_pulls():
    # family2 seeds 208/218/228 (docs/lidar_camera.md): 5.6-7.8 cm off along the optical axis with a bootstrap spread
    # of 1.3-2.2 cm, every restart back - accepted before the sector jackknife. Leaving one sector's matches out
    # moved them 4.4-19 cm along z: that move is part of the verdict sigma
    o = RefineOptions(coarse_search_deg=6.0, translation_prior_m=0.3)
    assert edge_verdict(_passing_checks(), o)[0]
    pulled = _passing_checks(sector_jackknife=[[0, 4, 120, 1e-4, -2e-4, 1e-4, 0.004, -0.003, 0.044]])  # scene, sector, n, rotvec, t
    ok, msg = edge_verdict(pulled, o)
    assert not ok and "weakly constrained" in msg and "one image region" in msg, msg
    assert sigma_for_verdict(pulled, o)[5] == pytest.approx(0.044)
    # a region that moves the result less than the limits changes nothing
    assert edge_verdict(_passing_checks(sector_jackknife=[[0, 4, 120, 1e-4, -2e-4, 1e-4, 0.004, -0.003, 0.012]]), o)[0]


@pytest.mark.slow
def test_sector_jackknife_sees_one_biased_region():
    # old seed 0 at the truth: leaving any sector out barely moves the pose; with the matched image lines of the
    # busiest sector moved 3 px towards the image centre (a region matched to the wrong parallel edge, a scale
    # bias = a depth bias) leaving a sector out moves it beyond the verdict's limits
    s = render_lidar_camera_scene(LidarCameraSceneParams(seed=0, duration_s=1.5, init_deg=3.0, init_m=0.10))
    sc = _edge_scene(s.camera, s.image, s.points, s.intensity, s.T_init)
    o = RefineOptions()
    idx, m, n, r = match_edges(sc, s.T_cam_lidar, o.radii_px[-1])
    clean = sector_jackknife([sc], [(idx, m, n, r)], s.T_cam_lidar, o)
    assert len(clean) >= 4
    assert np.degrees(np.abs(clean[:, 3:6]).max()) < 0.05 and np.abs(clean[:, 6:]).max() < 0.015, clean
    uv, _, _ = s.camera.project_from(s.T_cam_lidar, sc.lidar.points[idx])
    w, h = s.camera.image_size
    sector = np.clip((uv[:, 1] * 3 / h).astype(int), 0, 2) * 3 + np.clip((uv[:, 0] * 3 / w).astype(int), 0, 2)
    busiest = np.bincount(sector).argmax()
    inward = np.sign(np.sum((uv - np.array([w / 2, h / 2])) * n, 1)) * (sector == busiest)
    biased = sector_jackknife([sc], [(idx, m + 3.0 * inward[:, None] * n, n, r)], s.T_cam_lidar, o)
    assert np.degrees(np.abs(biased[:, 3:6]).max()) > o.max_bootstrap_sigma_deg or np.abs(biased[:, 6:]).max() > o.max_bootstrap_sigma_m, biased


@pytest.mark.slow
def test_precise_wrong_depth_is_refused():
    # family2 seed 228 (a corridor, Horizon-like, 640x512; one of the three false acceptances on seeds 200-229 at
    # ea1a654): 0.044 deg but 5.7 cm off, 5.6 cm of it along the optical axis, bootstrap spread 1.4 cm there. The CLI
    # defaults must refuse it, and the reported sigma must cover the depth error within 3 sigma
    s = render_family2_scene(Family2Params(seed=228, duration_s=1.0, init_deg=3.0, init_m=0.10))
    r = _refine(_edge_scene(s.camera, s.image, s.points, s.intensity, s.T_init), s.T_init)
    e_deg, e_m = geometry.pose_error(r.T_cam_lidar, s.T_cam_lidar)
    assert e_deg > 0.2 or e_m > 0.05, (e_deg, e_m)  # the case the check is for (a wrong result)
    assert not r.converged and r.message.startswith("did not converge"), r.message
    dT = r.T_cam_lidar @ np.linalg.inv(s.T_cam_lidar)
    assert abs(dT[2, 3]) <= 3 * r.sigma_bootstrap[5], (dT[2, 3], r.sigma_bootstrap)

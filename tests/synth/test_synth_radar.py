"""Radar-reflector scene generator: determinism, readable files, geometry against truth."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.extrinsics.radar import slant_predict
from radarcal.io import read_cloud
from radarcal.io.radar import read_radar_session
from radarcal.synth.radar import RadarRigSpec, RadarSceneSpec, generate_radar_session, reflector_offset, trihedral_points, write_radar_session


def _digest(folder):
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(p.relative_to(folder).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    spec = RadarSceneSpec(n_scenes=2, radar_sigma=0.02, ghost_rate=0.5, p_miss=0.1, lidar_noise=0.01, seed=5)
    a = write_radar_session(generate_radar_session(spec), tmp_path / "a")
    b = write_radar_session(generate_radar_session(spec), tmp_path / "b")
    spec.seed = 6
    c = write_radar_session(generate_radar_session(spec), tmp_path / "c")
    assert _digest(a) == _digest(b) != _digest(c)


def test_trihedral_geometry():
    apex = np.array([3.0, 1.0, 1.0])
    b = np.array([-1.0, -0.2, 0.1])
    pts = trihedral_points(apex, b, 0.3, 6)
    bu = b / np.linalg.norm(b)
    # the centroid lies on the boresight, reflector_offset in front of the apex
    np.testing.assert_allclose(pts.mean(axis=0), apex + reflector_offset(0.3) * bu, atol=1e-12)
    # every point lies on one of three mutually orthogonal plates through the apex
    rel = pts - apex
    _, s, _ = np.linalg.svd(rel[: len(rel) // 3])
    assert s[2] < 1e-9  # first plate is planar
    n = len(rel) // 3
    normals = [np.linalg.svd(rel[k * n:(k + 1) * n])[2][2] for k in range(3)]
    G = np.abs(np.array(normals) @ np.array(normals).T)
    np.testing.assert_allclose(G, np.eye(3), atol=1e-9)
    assert np.all(rel @ bu > 0)  # the opening faces the boresight


def test_files_load_and_radar_sits_at_truth(tmp_path):
    spec = RadarSceneSpec(rig=RadarRigSpec(extra_lidars={"lidar_left": (1.6, 1.0, 1.9, 0.0, 8.0, 70.0)}), n_scenes=3, radar_sigma=0.03, lidar_noise=0.0, seed=2, clutter=True)
    ses = generate_radar_session(spec)
    out = write_radar_session(ses, tmp_path / "s")
    sess = read_radar_session(out)  # the project's own reader
    truth = json.loads((out / "truth.json").read_text())
    assert sess.rig.main_lidar == "lidar_front" and sess.rig.radars == ["radar_left", "radar_middle", "radar_right"]
    assert sess.rig.mount_heights == {"radar_left": 0.55, "radar_middle": 0.5, "radar_right": 0.6}
    import open3d as o3d

    resid = []
    for sc, ts in zip(sess.scenes, truth["scenes"]):
        c = read_cloud(sc.clouds["lidar_front"])
        o = np.asarray(o3d.io.read_point_cloud(str(sc.clouds["lidar_front"])).points)
        assert len(o) == len(c) and np.allclose(o, c.points, atol=1e-6)
        assert "lidar_left" in sc.clouds
        # ground points of the main LiDAR lie on the vehicle's z = 0 plane through the true pose
        pv = geometry.transform_points(np.array(truth["T_vehicle_sensor"]["lidar_front"]), c.points.astype(float))
        assert np.mean(np.abs(pv[:, 2]) < 1e-5) > 0.3
        apex_v = np.array(ts["apex_vehicle"])
        for r in sess.rig.radars:
            T_v_r = np.array(truth["T_vehicle_sensor"][r])
            p = geometry.transform_points(geometry.invert_T(T_v_r), apex_v)
            pred = slant_predict(p[:, :2], p[:, 2])
            det = sc.detections.of(r)
            d = np.linalg.norm(pred[:, None] - det[None], axis=2).min(axis=1)
            resid += list(d[d < 0.2])
    resid = np.array(resid)
    # detections at the true (slant) reflector positions within the configured noise: |e| of a 2D Gaussian ~ Rayleigh
    assert len(resid) >= 15
    assert np.sqrt(np.mean(resid**2)) == pytest.approx(0.03 * np.sqrt(2), rel=0.35)


def test_quantisation_and_frames():
    spec = RadarSceneSpec(n_scenes=1, radar_sigma=0.01, quantisation=0.2, n_frames=5, ghost_rate=0.0, clutter=False, seed=1)
    r = generate_radar_session(spec).scenes[0]["radar"]
    xy = r["xy"]
    np.testing.assert_allclose(xy / 0.2, np.round(xy / 0.2), atol=1e-9)
    assert len(xy) % 5 == 0 and len(xy) >= 5 * 5

"""The LiDAR-camera scene generator agrees with its own geometry: LiDAR points projected with the true
T_cam_lidar land on the object the camera renders there; files load with radarcal's and OpenCV's readers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.synth.lidar_camera import LidarCameraSceneParams, render_lidar_camera_scene, rosette_directions, write_lidar_camera_scene


def _agreement(scene):
    uv, valid, _ = scene.camera.project_from(scene.T_cam_lidar, scene.points.astype(float))
    ins = valid & scene.camera.in_image(uv) & scene.cam_visible
    ij = np.round(uv[ins]).astype(int)
    return float(np.mean(scene.id_image[ij[:, 1], ij[:, 0]] == scene.point_ids[ins])), int(ins.sum())


@pytest.fixture(scope="module")
def scene():
    return render_lidar_camera_scene(LidarCameraSceneParams(seed=7, duration_s=0.5, boards=2, supersample=1))


def test_projected_points_hit_rendered_object(scene):
    agree, n = _agreement(scene)
    assert n > 20_000
    assert agree >= 0.99


def test_wrong_extrinsic_breaks_agreement(scene):
    # the check has teeth: a 1 deg error must lower the agreement clearly
    bad = type(scene)(**{**scene.__dict__, "T_cam_lidar": geometry.perturb_T(scene.T_cam_lidar, 1.0, 0.0, np.random.default_rng(0))})
    assert _agreement(bad)[0] < 0.97


def test_rosette_fov_and_rate():
    d = rosette_directions(100_000, 70.4)
    ang = np.degrees(np.arccos(np.clip(d[:, 0], -1, 1)))
    assert ang.max() == pytest.approx(35.2, abs=0.05)
    # non-repetitive: the second 0.5 s covers directions the first did not
    a, b = d[:50_000], d[50_000:]
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(a).query(b)
    assert np.median(dist) > 1e-5


def test_range_noise_matches_param(scene):
    # noise along the ray: re-cast-free check via the board planes (points on a board are within a few sigma)
    for b in scene.boards:
        m = scene.point_ids == b["id"]
        c = np.asarray(b["corners_lidar"])
        n = np.cross(c[1] - c[0], c[3] - c[0])
        n /= np.linalg.norm(n)
        d = (scene.points[m] - c[0]) @ n
        front = np.abs(d) < 0.2
        assert 0.01 < np.std(d[front]) < 0.035  # 2 cm along the ray, projected on the normal


def test_files_roundtrip(tmp_path, scene):
    import cv2

    from radarcal.bundle import load_bundle
    from radarcal.io import read_cloud, read_transform

    paths = write_lidar_camera_scene(scene, tmp_path)
    cloud = read_cloud(paths["cloud"])
    assert len(cloud) == len(scene.points) and cloud.intensity is not None
    img = cv2.imread(str(paths["image"]))
    assert img.shape == (1024, 1280, 3)
    truth = json.loads(paths["truth"].read_text())
    np.testing.assert_allclose(truth["T_cam_lidar"], scene.T_cam_lidar)
    T0 = read_transform(paths["init"])
    deg, m = geometry.pose_error(T0, scene.T_cam_lidar)
    assert deg == pytest.approx(3.0, abs=1e-6) and m == pytest.approx(0.10, abs=1e-6)
    b = load_bundle(paths["bundle"])
    assert np.allclose(b.camera("cam0").K, scene.camera.K)
    uv, _, _ = scene.camera.project_from(scene.T_cam_lidar, np.asarray(truth["boards"][0]["corners_lidar"]))
    np.testing.assert_allclose(uv, truth["boards"][0]["corners_uv"], atol=1e-9)


def test_pixel_rays_survive_a_margin_where_the_distortion_does_not_invert():
    """The ray grid reaches 16 px past the image; where the model cannot be inverted there (NaN), the rays inside the
    image must still be exact (family2 seeds 123/124 rendered all black: the spline spread one NaN everywhere)."""
    from radarcal.camera import Camera
    from radarcal.synth.lidar_camera import _pixel_rays

    K = np.array([[600.0, 0, 319.5], [0, 600.0, 255.5], [0, 0, 1]])
    cam = Camera((640, 512), K, np.zeros(5))
    exact = cam.unproject

    class MarginNaN(Camera):
        def unproject(self, uv):
            r = exact(uv)
            r[(uv[:, 0] < 0) | (uv[:, 1] < 0)] = np.nan
            return r

    broken = MarginNaN((640, 512), K, np.zeros(5))
    uv = np.stack(np.meshgrid(np.arange(0, 640, 7.0), np.arange(0, 512, 7.0)), -1).reshape(-1, 2)
    rays = _pixel_rays(broken, uv)
    assert np.isfinite(rays).all()
    truth = exact(uv)
    truth /= np.linalg.norm(truth, axis=1, keepdims=True)
    err_px = 600.0 * np.degrees(np.arccos(np.clip(np.sum(rays * truth, 1), -1, 1))) * np.pi / 180
    assert np.median(err_px) < 0.002 and err_px.max() < 0.5

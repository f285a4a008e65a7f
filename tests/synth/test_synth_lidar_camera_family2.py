"""The second LiDAR-camera scene family (held-out checks) agrees with its own geometry, and its scan patterns,
cameras and reflectivity are what the module says; the CLI writes it with ``--family family2``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.synth.lidar_camera_family2 import LAYOUTS, Family2Params, family2_camera, family2_lidar_directions, render_family2_scene


def _agreement(scene, T=None):
    uv, valid, _ = scene.camera.project_from(scene.T_cam_lidar if T is None else T, scene.points.astype(float))
    ins = valid & scene.camera.in_image(uv) & scene.cam_visible
    ij = np.round(uv[ins]).astype(int)
    return float(np.mean(scene.id_image[ij[:, 1], ij[:, 0]] == scene.point_ids[ins])), int(ins.sum())


@pytest.mark.parametrize("layout", LAYOUTS)
def test_projected_points_hit_rendered_object(layout):
    s = render_family2_scene(Family2Params(seed=1, layout=layout, lidar="horizon", duration_s=0.15, resolution="640x512"))
    agree, n = _agreement(s)
    assert n > 10_000
    assert agree >= 0.98, agree
    # the check has teeth: 2 deg off lowers the agreement (big walls stay the same object, so only by a few %)
    assert _agreement(s, geometry.perturb_T(s.T_cam_lidar, 2.0, 0.0, np.random.default_rng(0)))[0] < agree - 0.01
    # NIR reflectivity: 8-bit integers, not the visible albedo (other borders / contrasts)
    assert np.all(s.intensity == np.round(s.intensity)) and 0 <= s.intensity.min() and s.intensity.max() <= 255
    assert s.image.shape == (512, 640, 3) and s.image.dtype == np.uint8
    assert geometry.pose_error(s.T_init, s.T_cam_lidar) == pytest.approx((3.0, 0.10), abs=1e-6)


def test_scan_patterns_fov():
    rng = np.random.default_rng(0)
    # nominal FoVs; the Avia-like pattern's six lasers spread 4 % beyond the prisms' reach
    for kind, (h, v) in {"avia": (70.4 * 1.04, 77.2 * 1.04), "horizon": (81.7, 25.1)}.items():
        d = family2_lidar_directions(kind, 0.2, rng)
        az, el = np.degrees(np.arctan2(d[:, 1], d[:, 0])), np.degrees(np.arcsin(d[:, 2]))
        assert len(d) == 48_000
        assert np.abs(az).max() < h / 2 + 0.5 and np.abs(el).max() < v / 2 + 0.5
        assert np.abs(az).max() > h / 2 - 4 and np.abs(el).max() > v / 2 - 4  # fills the FoV
        # non-repetitive: the second 0.1 s does not retrace the first
        half = len(d) // 2
        assert np.median(np.linalg.norm(d[:half] - d[half:2 * half], axis=1)) > 1e-3
    d = family2_lidar_directions("spin32", 0.1, rng)
    el = np.degrees(np.arcsin(d[:, 2]))
    assert len(np.unique(np.round(el, 0))) > 25 and el.min() > -31.0 and el.max() < 11.0


def test_cameras_vary_and_are_invertible():
    rng = np.random.default_rng(5)
    cams = [family2_camera(rng) for _ in range(12)]
    assert {c.image_size for c in cams} == {(640, 512), (1280, 1024)}
    assert len({len(c.dist) for c in cams}) == 2  # radtan-5 and rational-8
    for c in cams:
        w, h = c.image_size
        uv = np.array([[0.0, 0.0], [w - 1.0, h - 1.0], [w / 2, 0.0]])
        back, ok = c.project(c.unproject(uv))
        assert np.all(ok) and np.allclose(back, uv, atol=1e-3)


def test_cli_family2(tmp_path, capsys):
    from radarcal.cli.main import main

    out = tmp_path / "s"
    assert main(["synth", "lidar-camera", "-o", str(out), "--family", "family2", "--seed", "4", "--lidar", "horizon", "--layout", "parking", "--duration", "0.1"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["params"]["family"] == "family2" and truth["params"]["layout"] == "parking" and truth["params"]["lidar"] == "horizon"
    assert "livox-horizon-like" in (out / "bundle.yaml").read_text()
    capsys.readouterr()
    assert main(["synth", "lidar-camera", "-o", str(tmp_path / "t"), "--family", "family2", "--lidar", "rosette2"]) == 2
    assert "error: --lidar" in capsys.readouterr().err
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("seed", [123, 124])
def test_strong_distortion_seeds_render_a_real_image(seed):
    """Seeds 123 (640x512) and 124 (1280x1024) draw a distortion that does not invert in the ray grid's margin past
    the image; the renderer used to spread that NaN over the whole image (all black, a NaN -> uint8 cast)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # "invalid value encountered in cast" was the symptom
        s = render_family2_scene(Family2Params(seed=seed, duration_s=0.1))
    img = s.image.astype(float)
    assert img.mean() > 30 and img.std() > 15  # black before the fix: mean 0, std 0
    assert np.mean(s.image.max(axis=2) == 0) < 0.001  # no black region either (rendering adds an 8-level floor)
    agree, n = _agreement(s)
    assert n > 1000 and agree >= 0.97, agree

"""Camera model against OpenCV's own projection (cv2.projectPoints / cv2.fisheye.projectPoints)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from radarcal.camera import Camera

W, H = 1280, 1024


def _K(rng, skew: float = 0.0) -> np.ndarray:
    f = rng.uniform(700, 1400)
    return np.array([[f * rng.uniform(0.995, 1.005), skew, W / 2 + rng.uniform(-30, 30)], [0, f, H / 2 + rng.uniform(-30, 30)], [0, 0, 1]])


def _radtan(rng, n: int, K: np.ndarray) -> np.ndarray:
    """Realistic OpenCV coefficients, redrawn until the radial map is monotonic out to 1.3x the image corner
    (a real lens is one-to-one over its image)."""
    r_corner = np.hypot(max(K[0, 2], W - K[0, 2]) / K[0, 0], max(K[1, 2], H - K[1, 2]) / K[1, 1])
    r = np.linspace(0, 1.3 * r_corner, 2000)
    while True:
        d = np.zeros(n)
        d[:4] = [rng.uniform(-0.35, 0.1), rng.uniform(-0.1, 0.15), rng.uniform(-2e-3, 2e-3), rng.uniform(-2e-3, 2e-3)]
        if n >= 5:
            d[4] = rng.uniform(-0.03, 0.03)
        if n >= 8:  # rational denominator, small
            d[5:8] = [rng.uniform(-0.05, 0.05), rng.uniform(-0.02, 0.02), rng.uniform(-0.01, 0.01)]
        if n >= 12:  # thin prism
            d[8:12] = rng.uniform(-1e-3, 1e-3, size=4)
        k = np.zeros(12)
        k[:n] = d
        r2 = r * r
        g = r * (1 + k[0] * r2 + k[1] * r2**2 + k[4] * r2**3) / (1 + k[5] * r2 + k[6] * r2**2 + k[7] * r2**3)
        if np.all(np.diff(g) > 0):
            return d


def _pixels_over_image(step: int = 40) -> np.ndarray:
    """A grid over the whole image including the four corner pixels and the edges."""
    us = np.unique(np.r_[np.arange(0, W, step), W - 1]).astype(float)
    vs = np.unique(np.r_[np.arange(0, H, step), H - 1]).astype(float)
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu.ravel(), vv.ravel()], axis=1)


def _points_for(cam: Camera, rng) -> np.ndarray:
    """3-D points in front of the camera at random depths whose images cover the whole frame (the tests check
    the coverage with OpenCV's projection, so this generator cannot hide a gap)."""
    rays = cam.unproject(_pixels_over_image())
    assert np.isfinite(rays).all()
    return rays * rng.uniform(0.5, 60.0, size=len(rays))[:, None]


@pytest.mark.parametrize("ncoef", [4, 5, 8, 12])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_radtan_projection_matches_cv2(ncoef, seed):
    rng = np.random.default_rng(100 * ncoef + seed)
    K = _K(rng)
    cam = Camera((W, H), K, _radtan(rng, ncoef, K))
    p = _points_for(cam, rng)
    uv, valid = cam.project(p)
    ref, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.dist)
    ref = ref.reshape(-1, 2)
    assert valid.all()
    assert np.abs(uv - ref).max() < 1e-9
    # the grid really spans the image: corners land near the corner pixels
    for corner in ([0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]):
        assert np.hypot(*(ref - corner).T).min() < 1e-6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fisheye_projection_matches_cv2(seed):
    rng = np.random.default_rng(seed)
    K = np.array([[rng.uniform(300, 500), 0, W / 2 + rng.uniform(-20, 20)], [0, 0, H / 2 + rng.uniform(-20, 20)], [0, 0, 1]])
    K[1, 1] = K[0, 0] * rng.uniform(0.998, 1.002)
    D = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.02, 0.02), rng.uniform(-5e-3, 5e-3), rng.uniform(-1e-3, 1e-3)])
    cam = Camera((W, H), K, D, model="fisheye")
    # rays up to ~80 degrees off axis, in all directions
    n = 3000
    theta = rng.uniform(0, np.radians(80), n)
    phi = rng.uniform(-np.pi, np.pi, n)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    p = rays * rng.uniform(0.3, 50, n)[:, None]
    p = np.vstack([p, [[0.0, 0.0, 2.0]]])  # the optical axis itself (r = 0)
    uv, valid = cam.project(p)
    ref, _ = cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    assert valid.all()
    assert np.abs(uv - ref.reshape(-1, 2)).max() < 1e-9
    np.testing.assert_allclose(uv[-1], K[:2, 2], atol=1e-12)


def test_fisheye_skew_matches_cv2_alpha():
    K = np.array([[400.0, 2.0, 640.0], [0, 401.0, 512.0], [0, 0, 1]])
    D = np.array([0.02, -0.01, 0.003, -0.0005])
    cam = Camera((W, H), K, D, model="fisheye")
    rng = np.random.default_rng(5)
    p = np.c_[rng.uniform(-2, 2, (500, 2)), rng.uniform(0.5, 3, 500)]
    ref, _ = cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D, alpha=K[0, 1] / K[0, 0])
    uv, _ = cam.project(p)
    assert np.abs(uv - ref.reshape(-1, 2)).max() < 1e-9


def test_pinhole_skew_is_applied():
    """cv2.projectPoints ignores K[0,1]; we apply it: u = fx*xd + s*yd + cx (checked by hand)."""
    K = np.array([[863.59, 0.1168, 621.67], [0, 863.10, 533.97], [0, 0, 1]])
    dist = np.array([-0.0944, 0.0947, -0.00808, 8.07e-05, 6.5e-05])
    cam = Camera((W, H), K, dist)
    p = np.array([[0.3, -0.2, 1.5], [-1.0, 0.8, 4.0]])
    uv, _ = cam.project(p)
    xyd = cam.distort(p[:, :2] / p[:, 2:])
    expect = np.stack([K[0, 0] * xyd[:, 0] + K[0, 1] * xyd[:, 1] + K[0, 2], K[1, 1] * xyd[:, 1] + K[1, 2]], axis=1)
    np.testing.assert_allclose(uv, expect, rtol=0, atol=1e-12)
    ref, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    np.testing.assert_allclose(uv[:, 0] - ref.reshape(-1, 2)[:, 0], K[0, 1] * xyd[:, 1], atol=1e-9)


K_WIDE = np.array([[650.0, 0, 640.5], [0, 649.0, 511.5], [0, 0, 1]])
# strong distortion: 430-970 px between the distorted and the undistorted image of the corner pixel
STRONG = {
    "radtan5_wide": ("pinhole", K_WIDE, np.array([-0.25, 0.05, 1.5e-3, -8e-4, -0.002])),
    "rational8_wide": ("pinhole", K_WIDE, np.array([1.2, 0.4, 1e-3, -1e-3, 0.01, 1.55, 0.75, 0.06])),
    "thinprism12_wide": ("pinhole", K_WIDE, np.array([-0.27, 0.06, 1e-3, 2e-3, -0.003, 0.01, 0.005, -0.002, 2e-3, -1e-3, 1.5e-3, 8e-4])),
    "fisheye_168deg": ("fisheye", np.array([[560.0, 0, 640.0], [0, 560.0, 512.0], [0, 0, 1]]), np.array([0.05, -0.03, 0.01, -0.002])),
}


@pytest.mark.parametrize("name", sorted(STRONG))
def test_unproject_inverts_project(name):
    model, K, dist = STRONG[name]
    cam = Camera((W, H), K, dist, model=model)
    uv = _pixels_over_image(step=16)
    rays = cam.unproject(uv)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    assert (rays[:, 2] > 0).all()
    uv2, valid = cam.project(rays * 7.3)
    assert valid.all()
    assert np.abs(uv2 - uv).max() < 1e-9
    # it is strong: the corner pixel sits hundreds of pixels from where a distortion-free lens would put it
    xy = rays[0, :2] / rays[0, 2]
    assert np.linalg.norm(K[:2, :2] @ xy + K[:2, 2] - uv[0]) > 300
    # and the other way: project then unproject gives back the ray direction
    rng = np.random.default_rng(3)
    p = rays * rng.uniform(0.5, 40, len(rays))[:, None]
    back = cam.unproject(cam.project(p)[0])
    assert np.abs(back - p / np.linalg.norm(p, axis=1, keepdims=True)).max() < 1e-11


def test_unproject_matches_cv2_undistort():
    K = np.array([[800.0, 0, 640.5], [0, 800.0, 511.5], [0, 0, 1]])
    dist = np.array([-0.3, 0.1, 1e-3, -5e-4, -0.01])
    cam = Camera((W, H), K, dist)
    uv = _pixels_over_image(step=64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, dist, None, None, None, crit).reshape(-1, 2)
    rays = cam.unproject(uv)
    np.testing.assert_allclose(rays[:, :2] / rays[:, 2:], xy, atol=1e-8)


def test_behind_camera_is_invalid():
    cam = Camera((W, H), [[800, 0, 640], [0, 800, 512], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
    p = np.array([[0.1, 0.2, 3.0], [0.1, 0.2, -3.0], [0.0, 0.0, 0.0], [1.0, 1.0, -1e-12], [np.nan, 0, 1]])
    uv, valid = cam.project(p)
    assert valid.tolist() == [True, False, False, False, False]
    assert np.isfinite(uv[0]).all() and np.isnan(uv[1:]).all()
    fe = Camera((W, H), [[330, 0, 640], [0, 330, 512], [0, 0, 1]], [0.0, 0.0, 0.0, 0.0], model="fisheye")
    uv, valid = fe.project(p)
    assert valid.tolist() == [True, False, False, False, False]


def test_project_from_and_in_image():
    cam = Camera((640, 480), [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]], np.zeros(5))
    T_cam_lidar = np.array([[0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, 0.0], [0, 0, 0, 1.0]])
    p_lidar = np.array([[10.0, 0.1, -0.2], [-5.0, 0, 0]])  # ahead, behind
    uv, valid, z = cam.project_from(T_cam_lidar, p_lidar)
    np.testing.assert_allclose(z, [10.0, -5.0])
    x, y = (-0.1 + 0.1) / 10.0, (0.2 + 0.2) / 10.0
    np.testing.assert_allclose(uv[0], [500 * x + 319.5, 500 * y + 239.5], atol=1e-12)
    assert valid.tolist() == [True, False]
    edge = np.array([[-0.5, -0.5], [639.5, 479.5], [-0.51, 10], [10, 479.51], [np.nan, 1]])
    assert cam.in_image(edge).tolist() == [True, True, False, False, False]
    assert cam.in_image(edge, margin=1.0).tolist() == [False, False, False, False, False]


def test_scaled_keeps_rays():
    cam = Camera((640, 480), [[500, 0, 319.5], [0, 502, 239.5], [0, 0, 1]], [-0.1, 0.01, 0, 0, 0])
    big = cam.scaled(2.0)
    assert big.image_size == (1280, 960)
    # pixel centre convention: the same ray hits (u+0.5)*2-0.5
    p = np.array([[0.3, -0.2, 2.0]])
    uv, _ = cam.project(p)
    uv2, _ = big.project(p)
    np.testing.assert_allclose(uv2, (uv + 0.5) * 2 - 0.5, atol=1e-9)


@pytest.mark.parametrize(
    "kwargs, msg",
    [
        (dict(K=np.diag([-500.0, 500, 1]), dist=np.zeros(5)), "focal lengths must be positive"),
        (dict(K=np.diag([500.0, 500, 1]), dist=np.zeros(6)), "pinhole needs 4/5/8/12 coefficients, got 6"),
        (dict(K=np.diag([500.0, 500, 1]), dist=np.zeros(5), model="fisheye"), "fisheye needs 4 coefficients, got 5"),
        (dict(K=np.diag([500.0, 500, 1]), dist=[0, np.nan, 0, 0]), "non-finite"),
        (dict(K=np.diag([500.0, 500, 1]), dist=np.zeros(4), model="kannala"), "model: expected one of"),
    ],
)
def test_camera_rejects(kwargs, msg):
    with pytest.raises(ValueError, match=msg):
        Camera((640, 480), **kwargs)


def test_dict_round_trip():
    cam = Camera((1280, 1024), [[863.590518437255, 0.116814496662654, 621.666074631063], [0, 863.100180533059, 533.971978652819], [0, 0, 1]],
                 [-0.0944205499243979, 0.0946727677776504, -0.00807970960613932, 8.07461209775283e-05, 6.52716646875879e-05])
    back = Camera.from_dict(cam.to_dict())
    assert back.image_size == cam.image_size and back.model == cam.model
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.dist, cam.dist)


def test_fisheye_unproject_beyond_90_degrees():
    """A fisheye that sees ~235 degrees across the diagonal: corner pixels map to rays behind the image plane
    (z < 0), and theta_d(theta) holds for every ray."""
    K = np.array([[400.0, 0, 640.0], [0, 400.0, 512.0], [0, 0, 1]])
    D = np.array([0.01, -0.002, 0.0003, -0.00002])
    cam = Camera((W, H), K, D, model="fisheye")
    uv = _pixels_over_image(step=32)
    rays = cam.unproject(uv)
    assert np.isfinite(rays).all()
    theta = np.arccos(np.clip(rays[:, 2], -1, 1))
    theta_d = theta * (1 + D[0] * theta**2 + D[1] * theta**4 + D[2] * theta**6 + D[3] * theta**8)
    xyd = (uv - K[:2, 2]) / [K[0, 0], K[1, 1]]
    np.testing.assert_allclose(theta_d, np.hypot(*xyd.T), atol=1e-12)
    phi_ok = np.hypot(*xyd.T) > 1e-9
    np.testing.assert_allclose(np.arctan2(rays[phi_ok, 1], rays[phi_ok, 0]), np.arctan2(xyd[phi_ok, 1], xyd[phi_ok, 0]), atol=1e-12)
    assert (rays[:, 2] < 0).any() and (rays[:, 2] > 0).any()
    behind = rays[:, 2] <= 0
    uv2, valid = cam.project(rays)
    assert not valid[behind].any() and valid[~behind].all()
    assert np.abs(uv2[~behind] - uv[~behind]).max() < 1e-9


def test_unproject_beyond_the_fold_is_nan():
    """Barrel distortion whose polynomial folds inside the image: pixels past the fold have no ray (NaN),
    pixels before it still round-trip."""
    K = np.array([[520.0, 0, 640.5], [0, 519.0, 511.5], [0, 0, 1]])
    cam = Camera((W, H), K, [-0.42, 0.21, 0.0, 0.0, -0.055])
    uv = np.array([[640.5, 511.5], [800.0, 600.0], [0.0, 0.0], [1279.0, 1023.0]])
    rays = cam.unproject(uv)
    assert np.isfinite(rays[:2]).all() and np.isnan(rays[2:]).all()
    assert np.abs(cam.project(rays[:2])[0] - uv[:2]).max() < 1e-9

"""Cloud queue, per-cloud depth images and box depth against brute-force references and known geometry."""

from __future__ import annotations

import numpy as np
import pytest
from runtime_scene import robot_cloud

from radarcal.geometry import invert_T, transform_points
from radarcal.runtime.fusion import BoxDepth, CloudQueue, make_depth_image, robust_depth, robust_depths


def test_depth_image_is_nearest_per_pixel(station):
    cam, T = station["camera"], station["T_cam_lidar"]
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(1, 40, 50000), rng.uniform(-15, 15, 50000), rng.uniform(-3, 3, 50000)]).astype(np.float32)
    pts = np.vstack([pts, pts[:5000] * 1.01])  # many pixels hit twice, the nearer must win
    img = make_depth_image(cam, T, pts, t=0.0)
    # brute-force reference: loop-free np.minimum.at into a dense image
    p_cam = transform_points(T, pts.astype(np.float64))
    uv, valid = cam.project(p_cam)
    ui, vi = np.rint(uv[:, 0]), np.rint(uv[:, 1])
    ok = valid & (ui >= 0) & (ui < 1280) & (vi >= 0) & (vi < 1024) & (p_cam[:, 2] > 0.3)
    ref = np.full(1280 * 1024, np.inf)
    np.minimum.at(ref, (vi[ok] * 1280 + ui[ok]).astype(np.int64), p_cam[ok, 2])
    ref = np.where(np.isinf(ref), np.nan, ref).reshape(1024, 1280)
    dense = img.dense()
    assert np.array_equal(np.isnan(dense), np.isnan(ref))
    np.testing.assert_allclose(dense[~np.isnan(dense)], ref[~np.isnan(ref)], rtol=2e-6)
    assert np.all(np.diff(img.pix) > 0)
    # box query == dense slice
    for box in [(100.2, 200.7, 400.0, 380.0), (0, 0, 1279, 1023), (-50, -50, 10, 10), (600, 600, 600, 600)]:
        got = np.sort(img.values_in_box(*box))
        u0, v0 = max(int(np.ceil(box[0])), 0), max(int(np.ceil(box[1])), 0)
        u1, v1 = min(int(np.floor(box[2])), 1279), min(int(np.floor(box[3])), 1023)
        want = dense[v0 : v1 + 1, u0 : u1 + 1]
        np.testing.assert_array_equal(got, np.sort(want[~np.isnan(want)]))


def test_robust_depth_picks_the_robot_not_background_or_strays():
    rng = np.random.default_rng(2)
    robot = 10.0 + rng.normal(0, 0.04, 40)
    background = 24.0 + rng.normal(0, 0.3, 150)
    stray = [3.0]
    d, sigma, n = robust_depth(np.concatenate([robot, background, stray]))
    assert abs(d - 10.0) < 0.03 and n == 40 and sigma < 0.05
    assert robust_depth(np.array([12.0, 30.0]))[0] == 12.0  # few points: the nearest
    assert robust_depth(np.array([])) is None
    assert robust_depth(np.array([np.nan])) is None


def _robust_depth_one_box(values, min_points=3, min_fraction=0.15, gap_m=0.35, gap_rel=0.03):
    """Reference: the statistic of :func:`robust_depth`, one box, written plainly."""
    v = np.sort(np.asarray(values, np.float32)[np.isfinite(values)])
    if len(v) == 0:
        return None
    if len(v) < min_points:
        return float(v[0]), max(float(v[-1] - v[0]), 0.05), len(v)
    cid = np.concatenate(([0], np.cumsum(np.diff(v) > np.maximum(gap_m, gap_rel * v[1:]))))
    counts = np.bincount(cid)
    ok = np.flatnonzero(counts >= max(min_points, int(np.ceil(min_fraction * len(v)))))
    sel = v[cid == (ok[0] if len(ok) else np.argmax(counts))]
    med = float(np.median(sel))
    return med, max(1.4826 * float(np.median(np.abs(sel - med))) / np.sqrt(len(sel)), 0.02), len(sel)


def test_robust_depths_of_many_boxes_equal_the_plain_one_box_statistic():
    rng = np.random.default_rng(4)
    for _ in range(200):
        B = int(rng.integers(1, 12))
        vals = [np.concatenate([rng.normal(rng.uniform(3, 25), 0.1, rng.integers(0, 30)), rng.uniform(2, 30, rng.integers(0, 5)),
                                np.round(rng.uniform(5, 20, rng.integers(0, 6)), 1)]).astype(np.float32) for _ in range(B)]  # fmt: skip
        owner = np.concatenate([np.full(len(v), i) for i, v in enumerate(vals)])
        mix = rng.permutation(len(owner))
        d, sigma, k = robust_depths(np.concatenate(vals)[mix], owner[mix], B)
        for i, v in enumerate(vals):
            ref = _robust_depth_one_box(v)
            assert (k[i] == 0) if ref is None else (float(d[i]), float(sigma[i]), int(k[i])) == ref


def test_depths_of_all_boxes_at_once_equal_one_box_at_a_time(station):
    """Boxes side by side and overlapping, with and without rectangles in front, sparse clouds (pooled over images)."""
    cam, T_cam_lidar, T_field_cam = station["camera"], station["T_cam_lidar"], station["T_field_cam"]
    T_lidar_field = invert_T(T_field_cam @ T_cam_lidar)
    rng = np.random.default_rng(5)
    q = CloudQueue(cam, T_cam_lidar, max_points=100_000, max_age_s=1.0)
    at = rng.uniform([6, 3], [22, 12], (6, 2))
    for k in range(4):
        q.push(0.1 * k, transform_points(T_lidar_field, np.vstack([robot_cloud((float(x), float(y)), n=40) for x, y in at])))
    uv, _ = cam.project(transform_points(invert_T(T_field_cam), np.column_stack([at, np.full(6, 0.25)])))
    centre = np.vstack([uv[rng.integers(0, 6, 34)] + rng.normal(0, 15, (34, 2)), rng.uniform([0, 0], [1280, 1024], (6, 2))])
    half = rng.uniform(5, 60, (40, 2))
    boxes = np.column_stack([centre - half, centre + half])
    excludes = [None if j % 3 else boxes[rng.choice(40, int(rng.integers(1, 4)))] for j in range(40)]
    batch = q.depths_in_boxes(boxes, t=0.35, max_age_s=0.3, excludes=excludes)
    single = [q.depth_in_box(b, t=0.35, max_age_s=0.3, exclude=e) for b, e in zip(boxes, excludes)]
    assert sum(bd is not None for bd in single) >= 10 and any(bd is not None and bd.images_used > 1 for bd in single)  # pooled
    plain = q.depths_in_boxes(boxes, t=0.35, max_age_s=0.3)
    assert any(a != b for a, b, e in zip(batch, plain, excludes) if e is not None)  # the rectangles in front matter
    assert batch == single
    assert batch == [_plain_box_depth(q, b, 0.35, 0.3, e) for b, e in zip(boxes, excludes)]


def _plain_box_depth(q: CloudQueue, box, t: float, max_age_s: float, exclude, shrink: float = 0.1) -> BoxDepth | None:
    """The reference: image by image, newest first, the dense image's pixels whose centres lie in the shrunk box and
    outside every rectangle of ``exclude``, pooled while fewer than 3."""
    x1, y1, x2, y2 = box
    dx, dy = (x2 - x1) * shrink, (y2 - y1) * shrink
    vals, used, oldest = [], 0, t
    for img in reversed(q.images):
        if t - img.t > max_age_s:
            break
        used += 1
        d = img.dense()
        vv, uu = np.mgrid[: d.shape[0], : d.shape[1]]
        m = np.isfinite(d) & (uu >= x1 + dx) & (uu <= x2 - dx) & (vv >= y1 + dy) & (vv <= y2 - dy)
        for ex in [] if exclude is None else exclude:
            m &= ~((uu >= ex[0]) & (uu <= ex[2]) & (vv >= ex[1]) & (vv <= ex[3]))
        if m.any():
            vals.append(d[m])
            oldest = img.t
        if sum(len(v) for v in vals) >= 3:
            break
    v = np.concatenate(vals) if vals else np.zeros(0, np.float32)
    r = robust_depth(v) if len(v) else None
    return None if r is None else BoxDepth(r[0], r[1], r[2], len(v), t - oldest, used)


def test_queue_budget_age_and_fallback(station):
    cam, T_cam_lidar, T_field_cam = station["camera"], station["T_cam_lidar"], station["T_field_cam"]
    T_lidar_field = invert_T(T_field_cam @ T_cam_lidar)
    q = CloudQueue(cam, T_cam_lidar, max_points=1000, max_age_s=0.5)
    robot = transform_points(T_lidar_field, robot_cloud((12.0, 7.0), n=300))
    q.push(0.0, robot)
    # the box around the robot: project its centre column
    T_cam_field = invert_T(T_field_cam)
    uv, _ = cam.project(transform_points(T_cam_field, np.array([[12.0, 7.25, 0.0], [12.0, 6.75, 0.5]])))
    box = (uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max())
    bd = q.depth_in_box(box, t=0.05)
    z_front = transform_points(T_cam_field, np.array([[11.75, 7.0, 0.25]]))[0, 2]
    assert bd is not None and abs(bd.depth - z_front) < 0.08 and bd.images_used == 1
    # a newer cloud that misses the box (points elsewhere): falls back to the older image
    other = transform_points(T_lidar_field, robot_cloud((20.0, 2.0), n=300))
    q.push(0.1, other)
    bd2 = q.depth_in_box(box, t=0.12)
    assert bd2 is not None and bd2.images_used == 2 and abs(bd2.depth - bd.depth) < 1e-6 and bd2.age_s == pytest.approx(0.12)
    # the point budget drops the oldest cloud (robot) once a third arrives -> the box is empty -> None
    q.push(0.2, other)
    assert len(q) == 3 or q.points <= 1000
    q.push(0.3, other)
    assert q.points <= 1000 and q.dropped >= 1
    assert q.depth_in_box(box, t=0.3) is None
    # the age limit
    q2 = CloudQueue(cam, T_cam_lidar, max_points=10**6, max_age_s=0.5)
    q2.push(0.0, robot)
    q2.push(0.4, other)
    assert q2.depth_in_box(box, t=0.45) is not None
    q2.push(0.7, other)
    assert len(q2) == 2 and q2.depth_in_box(box, t=0.7) is None
    q2.expire(5.0)
    assert len(q2) == 0 and q2.depth_in_box(box) is None


def test_surface_filter_terrain_walls_and_structures(station):
    from radarcal.runtime.fusion import SurfaceFilter

    class Field:  # a 0.6 m platform over x 10..14, y 5..9 on flat ground
        @staticmethod
        def surface_z(xy):
            return np.where((xy[:, 0] > 10) & (xy[:, 0] < 14) & (xy[:, 1] > 5) & (xy[:, 1] < 9), 0.6, 0.0)

    T_field_lidar = station["T_field_cam"] @ station["T_cam_lidar"]
    T_lidar_field = np.linalg.inv(T_field_lidar)
    outpost = {"center": [20.0, 3.0, 0.0], "size": [0.6, 0.6, 1.3], "yaw": 0.3}
    f = SurfaceFilter(T_field_lidar, Field.surface_z, structures=[outpost])
    pts = np.array([
        [5.0, 2.0, 0.01],     # ground: drop
        [12.0, 7.0, 0.62],    # platform top: drop
        [10.0, 7.0, 0.4],     # on the platform's wall (x = 10): drop
        [12.0, 7.0, 1.0],     # a robot standing on the platform: keep
        [5.0, 2.0, 0.3],      # a robot on the ground: keep
        [20.1, 3.1, 0.9],     # the outpost: drop
        [21.0, 3.0, 0.3],     # a robot beside the outpost: keep
    ])  # fmt: skip
    keep = f(transform_points(T_lidar_field, pts))
    assert keep.tolist() == [False, False, False, True, True, False, True]
    np.testing.assert_allclose(f.heights(transform_points(T_lidar_field, pts[[0, 3]])), [0.01, 0.4], atol=1e-5)


def test_surface_filter_tolerance_grows_with_range_on_raised_areas_only(station):
    """A 0.3 deg rotation error lifts a platform's far edge ~8-9 cm at 15 m: that return must not pass as a robot
    (it gave the depth of a robot hidden behind the platform, 2.7 m short); on the ground the 8 cm tolerance stays,
    so a far robot's lowest returns are kept."""
    from radarcal.runtime.background import range_sigma
    from radarcal.runtime.fusion import SurfaceFilter

    class Field:  # a 0.6 m platform over x 10..14, y 5..9 on flat ground; the LiDAR stands at x ~ -0.9
        @staticmethod
        def surface_z(xy):
            return np.where((xy[:, 0] > 10) & (xy[:, 0] < 14) & (xy[:, 1] > 5) & (xy[:, 1] < 9), 0.6, 0.0)

    T_field_lidar = station["T_field_cam"] @ station["T_cam_lidar"]
    T_lidar_field = np.linalg.inv(T_field_lidar)
    pts = np.array([
        [13.9, 7.0, 0.688],   # the platform's far edge, lifted 8.8 cm by the calibration error, 14.8 m out: drop
        [12.0, 7.0, 0.9],     # a robot standing on the platform: keep
        [25.0, 7.0, 0.12],    # a far robot's lowest return on the ground: keep
        [5.0, 2.0, 0.05],     # the ground: drop
    ])  # fmt: skip
    lidar_pts = transform_points(T_lidar_field, pts)
    fixed = SurfaceFilter(T_field_lidar, Field.surface_z)
    assert fixed(lidar_pts).tolist() == [True, True, True, False]  # the fixed 8 cm lets the lifted edge through
    grown = SurfaceFilter(T_field_lidar, Field.surface_z, raised_tol_of_range=lambda r: 1.2 * range_sigma(r, np.deg2rad(0.3), 0.02))
    assert grown(lidar_pts).tolist() == [False, True, True, False]


def test_box_exclusion_rectangles(station):
    cam, T = station["camera"], station["T_cam_lidar"]
    from radarcal.geometry import invert_T

    T_lidar_field = invert_T(station["T_field_cam"] @ T)
    q = CloudQueue(cam, T)
    near = robot_cloud((12.0, 7.4), height=0.8, n=400)  # tall enough to hide the far robot's lower part
    far = robot_cloud((16.0, 7.3), n=400)
    q.push(0.0, transform_points(T_lidar_field, np.vstack([near, far])))
    T_cam_field = invert_T(station["T_field_cam"])

    def box(c, h=0.45):
        ang = np.linspace(0, 2 * np.pi, 32)
        p = np.vstack([np.column_stack([c[0] + 0.25 * np.cos(ang), c[1] + 0.25 * np.sin(ang), np.full(32, z)]) for z in (0, h)])
        uv, _ = cam.project(transform_points(T_cam_field, p))
        return np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])

    b_near, b_far = box((12.0, 7.4), 0.8), box((16.0, 7.3))
    assert b_near[3] > b_far[3]  # the nearer robot's box reaches lower in the image
    z_far = transform_points(T_cam_field, np.array([[15.8, 7.3, 0.3]]))[0, 2]
    plain = q.depth_in_box(b_far)
    excl = q.depth_in_box(b_far, exclude=b_near[None])
    assert plain.depth < z_far - 3  # the occluding robot wins without exclusion
    assert abs(excl.depth - z_far) < 0.3


def test_box_depth_age_is_that_of_the_images_it_used(station):
    """Regression: a 2-point newest cloud over an expired one used to report the expired cloud's age
    (age_s=0.8, images_used=1); the depth comes from the newest cloud only, so its age is 0."""
    cam, T_cam_lidar, T_field_cam = station["camera"], station["T_cam_lidar"], station["T_field_cam"]
    T_lidar_field = invert_T(T_field_cam @ T_cam_lidar)
    T_cam_field = invert_T(T_field_cam)
    q = CloudQueue(cam, T_cam_lidar, max_points=10**6, max_age_s=1.0)
    q.push(0.0, transform_points(T_lidar_field, robot_cloud((12.0, 7.0), n=300)))
    uv, _ = cam.project(transform_points(T_cam_field, np.array([[12.0, 7.25, 0.0], [12.0, 6.75, 0.5]])))
    box = (uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max())
    two = transform_points(T_lidar_field, np.array([[11.75, 7.0, 0.2], [11.75, 7.05, 0.3]]))  # the robot's front face
    q.push(0.8, two)
    bd = q.depth_in_box(box, t=0.8, max_age_s=0.5)
    z_front = transform_points(T_cam_field, np.array([[11.75, 7.0, 0.25]]))[0, 2]
    assert bd is not None and bd.n_box == 2 and abs(bd.depth - z_front) < 0.1
    assert bd.images_used == 1 and bd.age_s == pytest.approx(0.0)
    # within the age limit both are pooled: the age is that of the oldest image that gave points
    bd = q.depth_in_box(box, t=0.8, max_age_s=1.0)
    assert bd.images_used == 2 and bd.n_box > 2 and bd.age_s == pytest.approx(0.8)


def test_queue_transforms_once_and_matches_filter_then_project(station):
    """The queue's single product (camera rows + field rows) gives the depth image of 'filter in the field frame,
    then project' done separately."""
    from radarcal.runtime.fusion import SurfaceFilter

    cam, T_cam_lidar, T_field_cam = station["camera"], station["T_cam_lidar"], station["T_field_cam"]
    T_field_lidar = T_field_cam @ T_cam_lidar
    rng = np.random.default_rng(5)
    p_field = np.column_stack([rng.uniform(0, 28, 40000), rng.uniform(0, 15, 40000), rng.choice([0.0, 0.02, 0.4, 1.0], 40000)])
    pts = transform_points(invert_T(T_field_lidar), p_field).astype(np.float32)
    flt = SurfaceFilter(T_field_lidar, structures=[{"center": [14, 7.5, 0], "size": [1, 1, 1.5], "yaw": 0.3}])
    q = CloudQueue(cam, T_cam_lidar, point_filter=flt)
    img = q.push(0.0, pts)
    ref = make_depth_image(cam, T_cam_lidar, pts[flt(pts)])
    assert img.n_points == len(pts) and 1000 < len(img.pix)
    np.testing.assert_array_equal(img.pix, ref.pix)
    np.testing.assert_allclose(img.depth, ref.depth, rtol=1e-6)

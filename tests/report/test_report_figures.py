"""Figure functions on synthetic arrays with known content: the plotted numbers must be the known ones."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.camera import Camera
from radarcal.geometry import T_from_xyz_rpy_deg, make_T
from radarcal.report import field as rf
from radarcal.report import intrinsics as ri
from radarcal.report import lidar_camera as rl
from radarcal.report._common import figure_to_png

CAM = Camera((640, 480), [[500.0, 0, 320.0], [0, 500.0, 240.0], [0, 0, 1]], np.zeros(5))


def _png_nonblank(fig) -> None:
    import cv2

    img = cv2.imdecode(np.frombuffer(figure_to_png(fig, dpi=50), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.std() > 5


# --- intrinsics -------------------------------------------------------------------------------------------------------
def test_per_view_bars_heights_and_outliers():
    err = np.array([0.2, 1.5, 0.25, 0.3, 2.0])
    out = np.array([False, True, False, False, True])
    fig = ri.per_view_error_figure([f"v{i}" for i in range(5)], err, out, threshold_px=1.0, rms_px=0.4)
    ax = fig.axes[0]
    bars = ax.patches
    assert np.allclose([b.get_height() for b in bars], err)
    red = np.array([b.get_facecolor()[0] > 0.8 and b.get_facecolor()[2] < 0.3 for b in bars])
    assert np.array_equal(red, out)
    assert [b.get_hatch() for b in bars] == [None, "//", None, None, "//"]
    assert "2 outliers" in ax.get_title()
    _png_nonblank(fig)
    with pytest.raises(ValueError):
        ri.per_view_error_figure(["a"], err)


def test_residual_vectors_scaled():
    uv = np.array([[100.0, 100.0], [300.0, 200.0], [500.0, 400.0]])
    r = np.array([[0.1, 0.0], [0.0, -0.2], [0.3, 0.4]])
    fig = ri.residual_vectors_figure(uv, r, (640, 480), scale=50.0)
    q = fig.axes[0].collections[0]
    assert np.allclose(q.U, r[:, 0] * 50) and np.allclose(q.V, r[:, 1] * 50)
    assert np.allclose(q.get_offsets(), uv)
    # auto scale: the 95th-percentile residual drawn as 4 % of the image diagonal
    from radarcal.report._common import auto_arrow_scale

    s = auto_arrow_scale(np.tile([[0.0, 0.5]], (100, 1)), (640, 480))
    assert s * 0.5 == pytest.approx(0.04 * 800.0)
    _png_nonblank(fig)


def test_residual_histogram_matches_gaussian():
    rng = np.random.default_rng(1)
    r = rng.normal(0, 0.2, (20000, 2))
    fig = ri.residual_histogram_figure(r, expected_sigma_px=0.2)
    ax = fig.axes[0]
    heights = np.array([p.get_height() for p in ax.patches[: len(ax.patches) // 2]])
    widths = np.array([p.get_width() for p in ax.patches[: len(ax.patches) // 2]])
    assert np.sum(heights * widths) == pytest.approx(1.0, abs=0.01)  # density of x residuals
    line = ax.lines[0]
    assert line.get_ydata().max() == pytest.approx(1 / (0.2 * np.sqrt(2 * np.pi)), rel=1e-3)
    centre = heights[len(heights) // 2 - 1 : len(heights) // 2 + 1].mean()
    assert centre == pytest.approx(1 / (0.2 * np.sqrt(2 * np.pi)), rel=0.1)
    observed = float(ax.get_title().split("observed σ = ")[1].split(" ")[0])
    assert observed == pytest.approx(0.2, abs=0.005)


def test_coverage_grid_counts_known_cells():
    uv = np.array([[5.0, 5.0], [6.0, 4.0], [9.4, 9.4], [635.0, 475.0], [700.0, 10.0], [np.nan, 3.0]])
    counts, ue, ve = ri.coverage_grid(uv, (640, 480), cells=(16, 12))
    assert counts.shape == (12, 16) and counts.sum() == 4
    assert counts[0, 0] == 3 and counts[11, 15] == 1
    fig = ri.coverage_figure(uv, (640, 480), cells=(16, 12))
    assert np.array_equal(np.asarray(fig.axes[0].images[0].get_array()), counts)
    assert "4 corners" in fig.axes[0].get_title()


def test_uncertainty_map_valid_region_contour():
    u = np.linspace(0, 639, 129)
    v = np.linspace(0, 479, 97)
    uu, vv = np.meshgrid(u, v)
    sigma = np.hypot(uu - 320, vv - 240) / 100.0 + 1e-3  # 1 px at radius 100 px
    mask = ri.valid_region(sigma, 1.0)
    assert mask.mean() == pytest.approx(np.pi * 100**2 / (640 * 480), rel=0.05)
    fig = ri.uncertainty_map_figure(u, v, sigma, (640, 480), 1.0)
    from matplotlib.contour import ContourSet

    cs = [c for c in fig.axes[0].collections if isinstance(c, ContourSet)]
    assert len(cs) == 1
    verts = np.concatenate([p.vertices for p in cs[0].get_paths() if len(p.vertices)])
    assert np.allclose(np.hypot(verts[:, 0] - 320, verts[:, 1] - 240), 100.0, atol=3.0)
    assert f"{mask.mean():.0%}" in fig.axes[0].get_title()
    with pytest.raises(ValueError):
        ri.uncertainty_map_figure(u, v, sigma.T, (640, 480), 1.0)


def test_distortion_displacement_analytic_k1():
    assert ri.distortion_displacement(CAM)[2].max() < 1e-9
    cam = Camera((640, 480), CAM.K, [-0.2, 0, 0, 0, 0])
    uv, d, mag = ri.distortion_displacement(cam, (9, 7))
    xy = (uv - [320.0, 240.0]) / 500.0
    r2 = np.sum(xy**2, axis=2, keepdims=True)
    assert np.allclose(d, 500.0 * xy * (-0.2) * r2, atol=1e-9)
    fig = ri.distortion_figure(cam)
    assert f"max {mag.max():.1f} px" in fig.axes[0].get_title()
    _png_nonblank(fig)


def test_projection_difference_known_shift_and_scale():
    u, v, d = ri.projection_difference(CAM, CAM)
    assert np.nanmax(d) < 1e-9
    K2 = CAM.K.copy()
    K2[0, 2] += 2.0
    _, _, d = ri.projection_difference(CAM, Camera((640, 480), K2, np.zeros(5)))
    assert np.allclose(d, 2.0, atol=1e-6)
    K3 = CAM.K.copy()
    K3[0, 0] = K3[1, 1] = 505.0
    u, v, d = ri.projection_difference(CAM, Camera((640, 480), K3, np.zeros(5)), (5, 4))
    uu, vv = np.meshgrid(u, v)
    assert np.allclose(d, np.hypot(uu - 320, vv - 240) * 5 / 500, atol=1e-6)
    fig = ri.crossval_difference_figure(u, v, d, (640, 480), sigma_px=1.0)
    assert "median" in fig.axes[0].get_title()


def test_parameter_table_values_and_sigma():
    assert ri.format_value_sigma(533.1234, 0.0456) == ("533.123", "0.046")
    assert ri.format_value_sigma(1.0, None) == ("1", "—")
    fig = ri.parameter_table_figure(["fx", "k1"], [533.1234, -0.2661], [0.0456, 0.0012], ["px", ""])
    tbl = fig.axes[0].tables[0]
    cells = tbl.get_celld()
    assert cells[(1, 0)].get_text().get_text() == "fx"
    assert cells[(1, 1)].get_text().get_text() == "533.123"
    assert cells[(2, 2)].get_text().get_text() == "0.0012"


# --- lidar-camera -------------------------------------------------------------------------------------------------------
T_CAM_LIDAR = make_T(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]), [0.0, 0.1, 0.0])  # lidar x fwd -> cam z


def test_cloud_overlay_projects_with_camera_and_depth_colours():
    rng = np.random.default_rng(2)
    p = np.c_[rng.uniform(2, 30, 500), rng.uniform(-5, 5, 500), rng.uniform(-2, 2, 500)]
    p = np.r_[p, [[-5.0, 0, 0], [3.0, 50.0, 0.0]]]  # behind the camera, far outside the image
    uv, z = rl.project_cloud(CAM, T_CAM_LIDAR, p, max_points=None)
    uv_ref, valid, z_ref = CAM.project_from(T_CAM_LIDAR, p)
    keep = valid & CAM.in_image(uv_ref)
    assert len(z) == keep.sum() and not keep[-2:].any()
    assert np.all(np.diff(z) <= 0)  # far-to-near drawing order
    order = np.argsort(-z_ref[keep], kind="stable")
    assert np.allclose(uv, uv_ref[keep][order]) and np.allclose(z, z_ref[keep][order])
    T_off = T_from_xyz_rpy_deg(0, 0.1, 0, 0, 3, 0) @ T_CAM_LIDAR
    fig = rl.cloud_overlay_figure(None, CAM, p, {"before": T_off, "after": T_CAM_LIDAR}, max_points=None)
    sc = fig.axes[1].collections[0]
    assert np.allclose(sc.get_offsets(), uv) and np.allclose(sc.get_array(), z)
    assert fig.axes[0].get_title().startswith("before")
    _png_nonblank(fig)


def test_edge_matches_and_histogram():
    a = np.array([[10.0, 10.0], [100.0, 50.0], [200.0, 300.0]])
    b = a + [[3.0, 4.0], [0.0, 1.0], [0.0, 0.0]]
    fig = rl.edge_matches_figure(None, (640, 480), a, b)
    lc = fig.axes[0].collections[0]
    assert np.allclose(lc.get_array(), [5.0, 1.0, 0.0])
    assert np.allclose(np.asarray(lc.get_segments()), np.stack([a, b], axis=1))
    r = np.abs(np.random.default_rng(3).normal(0, 1, 1000))
    fig = rl.edge_residual_histogram_figure(r, robust_scale_px=2.0)
    ax = fig.axes[0]
    assert sum(p.get_height() for p in ax.patches) == 1000
    assert ax.lines[0].get_xdata()[0] == pytest.approx(np.median(r))


def test_cost_profiles_quadratic_and_flat_parameter():
    x_opt = np.array([0.01, -0.02, 0.0, 0.1, 0.0, -0.05])
    a = np.array([100.0, 50.0, 80.0, 10.0, 20.0, 0.0])  # tz unobservable (flat)

    def cost(x):
        return 1.0 + float(np.sum(a * (x - x_opt) ** 2))

    off, c = rl.cost_profiles(cost, x_opt, [0.05, 0.05, 0.05, 0.2, 0.2, 0.2], n=11)
    assert off.shape == (6, 11) and np.allclose(off[:, 5], 0)
    assert np.allclose(c, 1.0 + a[:, None] * off**2)
    fig = rl.cost_profile_figure(off, c, display_scale=[np.degrees(1)] * 3 + [1.0] * 3)
    titles = [ax.get_title() for ax in fig.axes[:6]]
    assert "flat" in titles[5] and all("flat" not in t for t in titles[:5])
    mins = [ax.lines[1].get_xdata()[0] for ax in fig.axes[:5]]
    assert np.allclose(mins, 0.0)
    with pytest.raises(ValueError):
        rl.cost_profiles(cost, x_opt, [0.1], n=3)


# --- field / run ---------------------------------------------------------------------------------------------------------
def test_camera_position_and_landmark_figure():
    # camera at (-1, 7.5, 2.5) in the field, looking along +x
    R_field_cam = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    T_field_cam = make_T(R_field_cam, [-1.0, 7.5, 2.5])
    T_cam_field = np.linalg.inv(T_field_cam)
    c, d = rf.camera_position_on_field(T_cam_field)
    assert np.allclose(c, [-1, 7.5, 2.5]) and np.allclose(d, [1, 0, 0])
    lm = {"a": [0.0, 0.0, 0.0], "b": [28.0, 15.0, 0.0], "c": [14.0, 7.5, 0.6]}
    fig = rf.field_landmarks_figure((28.0, 15.0), lm, T_cam_field, picked=["a", "c"])
    ax = fig.axes[0]
    xs = {ln.get_label(): (np.asarray(ln.get_xdata()), np.asarray(ln.get_ydata())) for ln in ax.lines}
    assert np.allclose(xs["landmarks"][0], [0, 28, 14]) and np.allclose(xs["picked"][0], [0, 14])
    assert any(k.startswith("camera (z = 2.50") for k in xs)
    _png_nonblank(fig)


def test_picks_residual_arrows():
    picked = np.array([[100.0, 200.0], [400.0, 300.0]])
    reproj = picked - [[1.0, 0.0], [0.0, 2.0]]
    fig = rf.picks_residual_figure((640, 480), ["L1", "L2"], picked, reproj, scale=10)
    q = [c for c in fig.axes[0].collections if hasattr(c, "U")][0]
    assert np.allclose(q.U, [10, 0]) and np.allclose(q.V, [0, 20])
    assert "RMS 1.58 px" in fig.axes[0].get_title()


def test_localisation_error_map_and_tracks():
    x = np.linspace(0, 28, 57)
    y = np.linspace(0, 15, 31)
    xx, yy = np.meshgrid(x, y)
    s = 0.01 * np.hypot(xx + 1, yy - 7.5)
    s[:, -3:] = np.nan
    fig = rf.localisation_error_figure(x, y, s, (28, 15))
    mesh = [c for c in fig.axes[0].collections if hasattr(c, "get_array") and c.get_array() is not None and np.size(c.get_array()) == s.size][0]
    assert np.allclose(np.ma.filled(mesh.get_array(), np.nan).ravel(), s.ravel(), equal_nan=True)
    assert f"median {np.nanmedian(s):.2f} m" in fig.axes[0].get_title()
    with pytest.raises(ValueError):
        rf.localisation_error_figure(x, y, s.T, (28, 15))
    t = np.linspace(0, 10, 101)
    tracks = {"R1": np.c_[2 + t, 3 + 0 * t], "B3": np.c_[20 - t, 10 + 0.1 * t]}
    fig = rf.minimap_tracks_figure((28, 15), tracks, truth=tracks)
    lines = {ln.get_label(): ln for ln in fig.axes[0].lines}
    assert np.allclose(lines["R1"].get_xdata(), 2 + t)
    err = {"R1": np.full_like(t, 0.1), "B3": np.full_like(t, 0.3)}
    fig = rf.error_over_time_figure({"R1": t, "B3": t}, err)
    labels = [ln.get_label() for ln in fig.axes[0].lines]
    assert "median 0.20 m" in labels
    _png_nonblank(fig)


# --- issue 17: team colours, visible overlay points, the σ table's title ---------------------------------------------
def test_team_colours_blue_4_is_blue():
    from matplotlib.colors import to_rgb

    from radarcal.teams import TEAM_SHADES, team_of, track_colours

    labels = ["red_1", "red_3", "red_4", "blue_1", "blue_3", "blue_4", "B7", "R2", "#12"]
    col = track_colours(labels)
    assert team_of("blue_4") == "blue" and team_of("R2") == "red" and team_of("#12") is None
    for lab in labels:
        r, g, b = to_rgb(col[lab])
        if team_of(lab) == "blue":
            assert col[lab] in TEAM_SHADES["blue"] and b > r + 0.2, lab
        elif team_of(lab) == "red":
            assert col[lab] in TEAM_SHADES["red"] and r > b + 0.2, lab
        else:
            assert abs(r - b) < 0.05, lab  # grey
    assert col["blue_4"] == track_colours(["blue_4"])["blue_4"]  # the shade follows the robot, not the other labels
    assert len({col[k] for k in ("blue_1", "blue_3", "blue_4")}) == 3  # robots of a team stay apart


def test_minimap_and_error_figures_use_the_team_colours():
    from matplotlib.colors import to_hex

    from radarcal.teams import track_colours

    # before: tab10 by sorted order made blue_4 (4th label) tab:red
    tracks = {k: np.c_[np.linspace(1, 5, 10), np.full(10, i + 1.0)] for i, k in enumerate(["blue_1", "blue_2", "blue_3", "blue_4", "red_1"])}
    fig = rf.minimap_tracks_figure((28.0, 15.0), tracks)
    lines = {ln.get_label(): to_hex(ln.get_color()) for ln in fig.axes[0].lines if ln.get_label() in tracks}
    assert lines == track_colours(tracks)
    r, g, b = (int(lines["blue_4"][i : i + 2], 16) for i in (1, 3, 5))
    assert b > r
    fig = rf.error_over_time_figure({k: np.arange(10.0) for k in tracks}, {k: np.full(10, 0.1) for k in tracks})
    lines = {ln.get_label(): to_hex(ln.get_color()) for ln in fig.axes[0].lines if ln.get_label() in tracks}
    assert lines == track_colours(tracks)


def test_overlay_points_visible_on_a_large_image():
    """A 1920x1200 camera: the overlay's dots are at least 2 pt (2.7 px at 96 dpi) across, and each renders to a
    visible blob of pixels (they were 0.6 pt² = 1 px, invisible at report scale)."""
    from radarcal.report._common import MIN_POINT_DIAMETER_PT, figure_to_png

    cam = Camera((1920, 1200), [[1400.0, 0, 960], [0, 1400.0, 600], [0, 0, 1]], np.zeros(5))
    u, v = np.meshgrid(np.linspace(150, 1770, 8), np.linspace(150, 1050, 5))  # 40 dots well apart over the image
    p_cam = np.c_[(u.ravel() - 960) / 1400 * 10, (v.ravel() - 600) / 1400 * 10, np.full(40, 10.0)]

    def dots(fig):
        import cv2

        img = cv2.imdecode(np.frombuffer(figure_to_png(fig, dpi=96), np.uint8), cv2.IMREAD_COLOR)
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        coloured = (hsv[..., 1] > 100) & (hsv[..., 2] > 60)
        bbox = fig.axes[0].get_window_extent()  # inside the image axes (the colour bar is coloured too)
        h = img.shape[0]
        inside = coloured[int(h - bbox.y1) + 2 : int(h - bbox.y0) - 2, int(bbox.x0) + 2 : int(bbox.x1) - 2].astype(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(inside)
        return stats[1:, cv2.CC_STAT_AREA]

    fig = rl.cloud_overlay_figure(None, cam, p_cam, {"after": np.eye(4)}, depth_range=(9.0, 11.0))
    assert np.all(np.sqrt(fig.axes[0].collections[0].get_sizes()) >= MIN_POINT_DIAMETER_PT)
    areas = dots(fig)
    assert len(areas) == 40 and areas.min() >= 4, areas  # every dot drawn, each at least 2x2 px
    old = dots(rl.cloud_overlay_figure(None, cam, p_cam, {"after": np.eye(4)}, depth_range=(9.0, 11.0), point_size=0.6))  # the old size
    assert len(old) < 40 or old.min() < 4  # control: the 1-px dots fail the same check


def test_sigma_table_titled_by_what_it_shows():
    from radarcal.report.html import Table
    from radarcal.report.lidar_camera_section import lidar_camera_section

    cam = Camera((640, 480), [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]], np.zeros(5))
    both = {"edge_rot_deg": [0.05, 0.02, 0.04], "edge_trans_m": [0.003, 0.008, 0.002], "edge_bootstrap_rot_deg": [0.11, 0.07, 0.09], "edge_bootstrap_trans_m": [0.01, 0.02, 0.005]}
    sec = lidar_camera_section("lidar_camera/cam0_lidar0", cam, {"T_final": np.eye(4)}, {}, transform_sigma=both)
    t = next(it for it in sec.items if isinstance(it, Table))
    assert t.columns == ["parameter", "σ (block bootstrap)", "σ (Jacobian)", "unit"]
    assert "block bootstrap" in t.caption and "Jacobian" in t.caption
    assert t.rows[0][:3] == ["rx", "0.11", "0.05"] and t.rows[5][:3] == ["tz", "0.005", "0.002"]
    boot = {k: v for k, v in both.items() if "bootstrap" in k}
    t = next(it for it in lidar_camera_section("k/c_l", cam, {"T_final": np.eye(4)}, {}, transform_sigma=boot).items if isinstance(it, Table))
    assert "Jacobian" not in t.caption and "block bootstrap" in t.caption and t.rows[1][1] == "0.07"
    jac = {k: v for k, v in both.items() if "bootstrap" not in k}
    t = next(it for it in lidar_camera_section("k/c_l", cam, {"T_final": np.eye(4)}, {}, transform_sigma=jac).items if isinstance(it, Table))
    assert "bootstrap" not in t.caption and "Jacobian" in t.caption and t.rows[1][1] == "0.02"

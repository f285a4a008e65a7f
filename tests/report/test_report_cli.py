"""`radarcal report` end to end on a bundle with generated session files of known content, and the HTML rendered by
headless Chromium (when installed) to check that the page is not blank and shows its figures."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from radarcal.bundle import Bundle, save_bundle
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.intrinsics.session import IntrinsicsSession
from radarcal.pnp.session import FieldPnPSession
from radarcal.camera import Camera
from radarcal.cli.main import main as cli
from radarcal.geometry import T_from_xyz_rpy_deg, make_T
from radarcal.report.html import Section, Table, inline_pngs, render_html

CAM = Camera((1280, 1024), [[1000.0, 0, 640.0], [0, 1000.0, 512.0], [0, 0, 1]], [-0.12, 0.05, 0.0005, -0.0003, 0.0])
T_CAM_LIDAR = make_T(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]), [0.02, 0.1, 0.05])


def _intrinsics_session(rng):
    """Board corners seen in 12 views, projected with CAM, plus 0.2 px noise; view 3 carries 2 px noise."""
    obj = np.stack(np.meshgrid(np.arange(9) * 0.05, np.arange(6) * 0.05), -1).reshape(-1, 2)
    obj = np.c_[obj, np.zeros(len(obj))]
    uv_all, res_all, vidx = [], [], []
    for v in range(12):
        T = T_from_xyz_rpy_deg(rng.uniform(-0.4, 0.2), rng.uniform(-0.3, 0.1), rng.uniform(0.8, 1.4), rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-10, 10))
        uv, valid, _ = CAM.project_from(T, obj)
        noise = rng.normal(0, 2.0 if v == 3 else 0.2, uv.shape)
        uv_all.append(uv + noise)
        res_all.append(noise)
        vidx.append(np.full(len(uv), v))
    uv, res, vidx = np.concatenate(uv_all), np.concatenate(res_all), np.concatenate(vidx)
    u = np.linspace(0, 1279, 33)
    v = np.linspace(0, 1023, 27)
    uu, vv = np.meshgrid(u, v)
    sigma = 0.05 + (np.hypot(uu - 640, vv - 512) / 600.0) ** 2
    view_rms = np.sqrt(np.bincount(vidx, np.sum(res**2, axis=1)) / np.bincount(vidx))
    return IntrinsicsSession(corners_uv=uv, residuals=res, corner_view=vidx, names=np.array([f"img{i:02d}.png" for i in range(12)]), status=np.array(["used"] * 12),
                             view_index=np.arange(12), view_rms_px=view_rms, view_used=view_rms <= 1.0, uncertainty_u=u, uncertainty_v=v, uncertainty_sigma_px=sigma,
                             crossval_u=u, crossval_v=v, crossval_diff_px=0.5 * sigma, camera="cam0", noise_px=0.2, uncertainty_threshold_px=0.2)  # fmt: skip


@pytest.fixture(scope="module")
def bundle_path(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("report")
    rng = np.random.default_rng(0)
    b = Bundle(path=tmp_path / "calib.yaml")
    b.set_camera("cam0", CAM, rms_px=0.21, sigma={"fx": 0.31, "fy": 0.3, "cx": 0.25, "cy": 0.22})
    b.set_transform("cam0", "lidar0", T_CAM_LIDAR, method="edges")
    T_field_cam = make_T(np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]]) @ T_from_xyz_rpy_deg(0, 0, 0, 20, 0, 0)[:3, :3], [-1.0, 7.5, 2.5])
    b.set_transform("cam0", "field", np.linalg.inv(T_field_cam), method="field-pnp")
    b.field_model = {"name": "test", "size": [28.0, 15.0], "landmarks": {"a": [0, 0, 0], "b": [28, 15, 0], "c": [14, 7.5, 0.6], "d": [10, 2, 0]}, "outline": [[0, 0], [28, 0], [28, 15], [0, 15]]}
    import cv2

    for i in range(12):  # the views' images, named by the session (the worst kept view is drawn over its image)
        cv2.imwrite(str(tmp_path / f"img{i:02d}.png"), np.full((1024, 1280), 60 + 10 * i, np.uint8))
    cv2.imwrite(str(tmp_path / "field.png"), np.full((1024, 1280, 3), 120, np.uint8))
    _intrinsics_session(rng).save(b, "intrinsics/cam0")
    # the layout `radarcal lidar-camera --refine` writes; the image and cloud are named (relative) in meta "pairs"
    from radarcal.io import write_pcd

    pts = np.c_[rng.uniform(2, 30, 20000), rng.uniform(-8, 8, 20000), rng.uniform(-2, 4, 20000)]
    write_pcd(tmp_path / "cloud.pcd", pts)
    cv2.imwrite(str(tmp_path / "scene.png"), np.full((1024, 1280, 3), 100, np.uint8))
    a = rng.uniform([0, 0], [1280, 1024], (300, 2))
    x = np.linspace(-1, 1, 9)
    LidarCameraSession(
        T_init=T_from_xyz_rpy_deg(0.05, 0, 0, 2, 1, 0) @ T_CAM_LIDAR, T_final=T_CAM_LIDAR, scene_matches={"scene0_uv": a, "scene0_line_point": a + rng.normal(0, 1, a.shape)},
        residuals_before=rng.normal(0, 5, 280), residuals_after=rng.normal(0, 0.5, 300), profile_offsets=np.stack([x * (0.02 if i < 3 else 0.1) for i in range(6)]),
        profile_costs=np.stack([1 + x**2] * 6), camera="cam0", lidar="lidar0", init="init.json", method="edge-alignment", converged=True, pairs=[["scene.png", "cloud.pcd"]],
    ).save(b, "lidar_camera/cam0_lidar0")  # fmt: skip
    b.transforms["T_cam0_lidar0"].sigma = {"edge_rot_deg": [0.05, 0.02, 0.04], "edge_trans_m": [0.003, 0.008, 0.002]}
    xg = np.linspace(0, 28, 29)
    yg = np.linspace(0, 15, 16)
    xx, yy = np.meshgrid(xg, yg)
    picked = np.array([[100.0, 800], [1200, 300], [640, 400], [300, 900]])
    reproj = np.array([[100.5, 800.2], [1199, 300.4], [640.3, 399.5], [300.0, 901.0]])
    FieldPnPSession(names=np.array(["a", "b", "c", "d"]), uv=picked, residuals_px=picked - reproj, grid_x=xg, grid_y=yg, sigma_ground=0.02 * np.hypot(xx + 1, yy - 7.5),
                    camera="cam0", field="test", image=str(tmp_path / "field.png")).save(b, "field_pnp/cam0")  # fmt: skip
    save_bundle(b, b.path)
    tracks = tmp_path / "track.jsonl"
    truth = tmp_path / "truth.jsonl"
    t = np.arange(50) * 0.1
    with open(tracks, "w") as f, open(truth, "w") as g:
        for ti in t:
            f.write(json.dumps({"t": ti, "robots": [{"label": "R1", "x": 2 + ti + 0.1, "y": 3.0}, {"label": "B3", "x": 20 - ti, "y": 10.0, "z": 0.0}]}) + "\n")
            g.write(json.dumps({"t": ti, "robots": [{"label": "R1", "x": 2 + ti, "y": 3.0}, {"label": "B3", "p_field": [20 - ti, 10.2, 0.0]}]}) + "\n")
    return b.path


@pytest.fixture(scope="module")
def full_report(bundle_path):
    """The report of the generated bundle with tracks and truth, rendered once for the tests below."""
    import contextlib
    import io

    d = bundle_path.parent
    out = d / "report.html"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli(["report", str(bundle_path), "-o", str(out), "--tracks", str(d / "track.jsonl"), "--truth", str(d / "truth.jsonl"), "--dpi", "50", "--json"])
    assert rc == 0
    return out, json.loads(buf.getvalue())


def test_report_cli_writes_every_section(full_report):
    out, s = full_report
    assert s["skipped"] == []
    titles = s["sections"]
    assert titles == ["Bundle overview", "Intrinsics: cam0", "LiDAR-camera: cam0_lidar0", "Field pose: cam0", "Run: tracks"]
    # intrinsics 7 + the worst kept view over its image + lidar-camera 4 + field 3 + run 2
    assert s["figures"] == 17
    html = out.read_text()
    pngs = inline_pngs(html)
    assert len(pngs) == 17
    assert "http://" not in html and "https://" not in html and "<script" not in html
    import cv2

    for png in pngs:
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert img is not None and img.std() > 5
    assert "0.31" in html  # σ of fx from the bundle in the parameter table


def test_run_section_error_against_truth(bundle_path):
    from radarcal.report.build import read_tracks, run_section

    d = bundle_path.parent
    sec = run_section(*read_tracks(d / "track.jsonl"), None, *read_tracks(d / "truth.jsonl"))
    figs = [it for it in sec.items if hasattr(it, "savefig")]
    assert len(figs) == 2
    # the track file is off by 0.1 m (R1, in x) and 0.2 m (B3, in y) at every time: median 0.15 m
    labels = [ln.get_label() for ln in figs[1].axes[0].lines]
    assert "median 0.15 m" in labels and "95th pct 0.20 m" in labels
    e = {ln.get_label(): np.asarray(ln.get_ydata()) for ln in figs[1].axes[0].lines}
    assert np.allclose(e["R1"], 0.1, atol=1e-6) and np.allclose(e["B3"], 0.2, atol=1e-6)


def test_report_session_dir_and_errors(tmp_path, capsys):
    b = Bundle(path=tmp_path / "calib.yaml")
    b.set_camera("cam0", CAM)
    IntrinsicsSession(corners_uv=np.array([[10.0, 10.0], [500.0, 600.0]])).save(b, "intrinsics/cam0")
    save_bundle(b, b.path)
    bundle_path = b.path
    # the session folder moved elsewhere: --session finds the files by name
    moved = tmp_path / "moved"
    shutil.move(str(tmp_path / "calib.sessions"), moved)
    out = tmp_path / "r.html"
    assert cli(["report", str(bundle_path), "-o", str(out), "--session", str(moved), "--dpi", "30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sections"] == ["Bundle overview", "Intrinsics: cam0"]
    # without --session the report names the missing file
    assert cli(["report", str(bundle_path), "-o", str(out)]) == 2
    assert "session file not found" in capsys.readouterr().err
    assert cli(["report", str(tmp_path / "nope.yaml"), "-o", str(out)]) == 2
    assert cli(["report", str(bundle_path), "-o", str(out), "--session", str(moved), "--tracks", str(tmp_path / "none.jsonl")]) == 2
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"t": 0, "robots": [{"label": "R1", "x": 1, "y": 2}]}\nnot json\n')
    assert cli(["report", str(bundle_path), "-o", str(out), "--session", str(moved), "--tracks", str(bad)]) == 2
    assert "line 2" in capsys.readouterr().err


def test_report_skips_what_a_session_lacks(tmp_path, capsys):
    b = Bundle(path=tmp_path / "b.yaml")
    b.set_camera("cam0", CAM)
    IntrinsicsSession(corners_uv=np.array([[10.0, 10.0], [500.0, 600.0]])).save(b, "intrinsics/cam0")
    save_bundle(b, b.path)
    assert cli(["report", str(b.path), "-o", str(tmp_path / "r.html"), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["figures"] == 2  # coverage + distortion field: all that corners alone allow
    assert any("residual" in k for k in s["skipped"])
    assert "not available" in (tmp_path / "r.html").read_text()


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    return None


def _screenshot(html_path: Path, png_path: Path, size=(1300, 2400)) -> np.ndarray:
    import cv2

    exe = _chromium()
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run", "--hide-scrollbars", f"--window-size={size[0]},{size[1]}", f"--screenshot={png_path}", html_path.resolve().as_uri()]
    subprocess.run(cmd, capture_output=True, timeout=60, check=False)
    img = cv2.imread(str(png_path), cv2.IMREAD_COLOR)
    assert img is not None, "chromium wrote no screenshot"
    return img


def _display_heights(html: str) -> list[float]:
    """Display height (px) of every inline figure: width attribute × the PNG's aspect ratio."""
    import base64
    import re

    import cv2

    out = []
    for m in re.finditer(r'<img alt="[^"]*" width="(\d+)" src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(m.group(2)), np.uint8), cv2.IMREAD_GRAYSCALE)
        out.append(int(m.group(1)) * img.shape[0] / img.shape[1])
    return out


def _content_bottom(img: np.ndarray) -> int:
    """Last screenshot row that differs from the page background (#f6f7f9)."""
    bg = np.all(np.abs(img.astype(int) - [249, 247, 246]) <= 2, axis=2)
    rows = np.nonzero(~bg.all(axis=1))[0]
    return int(rows.max()) if rows.size else 0


@pytest.mark.skipif(_chromium() is None, reason="no headless Chromium installed (apt-get install chromium); the inline PNGs are checked by test_report_cli_writes_every_section")
def test_report_renders_in_chromium(full_report, tmp_path):
    import cv2

    out, _ = full_report
    heights = _display_heights(out.read_text())
    assert len(heights) == 17
    img = _screenshot(out, tmp_path / "report.png", (1300, int(sum(heights)) + 2500))  # tall enough for the whole page
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    assert gray.std() > 20, "the rendered page is blank"
    # every figure was decoded and laid out at its full size (a broken image collapses to an icon): the page is at
    # least as tall as the figures stacked
    assert _content_bottom(img) >= sum(heights), f"page ends at {_content_bottom(img)} px, figures need {sum(heights):.0f} px"
    # the figures are drawn: coloured content over a good part of the page, down to the last section (run tracks)
    page = img[: _content_bottom(img)]
    sat = cv2.cvtColor(page, cv2.COLOR_BGR2HSV)[..., 1] > 80
    assert float(np.mean(sat.any(axis=1))) > 0.3
    tail = page[-int(heights[-1]) - 40 :]  # the last figure (error over time) and the section's bottom padding
    dark = cv2.cvtColor(tail, cv2.COLOR_BGR2GRAY) < 160  # axes frame, ticks, labels
    assert dark.any(axis=1).mean() > 0.5 and sat[-int(heights[-1]) - 40 :].any(), "the last figure (error over time) is not drawn"
    # known content: the outlier view (view 3, 2 px noise) is a saturated red bar in the first figure
    b, g, r = (page[..., i].astype(int) for i in range(3))
    red = (r > 150) & (g < 90) & (b < 90)  # tab:red = (214, 39, 40)
    assert red[:3000].sum() > 300, "the outlier bar of the per-view error figure is not visible"

    # negative control: a page with two figures, the second one's PNG corrupted, ends above the stacked figures
    from radarcal.report import intrinsics as ri

    figs = [ri.per_view_error_figure(["a", "b"], np.array([1.0, 2.0])), ri.coverage_figure(np.array([[10.0, 10.0]]), (640, 480))]
    good = render_html("control", [Section("two figures", figs)], dpi=40)
    i = good.rindex("base64,") + 7
    broken = tmp_path / "broken.html"
    broken.write_text(good[:i] + "AAAA" + good[i + 400 :])
    h = _display_heights(good)
    ok_page, bad_page = tmp_path / "ok.html", broken
    ok_page.write_text(good)
    assert _content_bottom(_screenshot(ok_page, tmp_path / "ok.png", (1000, 2000))) >= sum(h)
    assert _content_bottom(_screenshot(bad_page, tmp_path / "bad.png", (1000, 2000))) < sum(h) - h[1] / 2


def test_stereo_section_per_pair_rms():
    from radarcal.report.build import stereo_section

    # pair k: every corner off by (k+1)*0.1 px in x in both cameras -> RMS per pair (k+1)*0.1 px; one outlier corner ignored
    pair = np.repeat(np.arange(3), 4)
    r0 = np.c_[(pair + 1) * 0.1, np.zeros(12)]
    r0[0] = [50.0, 0.0]
    inl = np.ones(12, bool)
    inl[0] = False
    arrays = {"residuals0": r0, "residuals1": r0.copy(), "pair_of_corner": pair, "inliers": inl, "pair_names": np.array([["l1.png", "r1.png"], ["l2.png", "r2.png"], ["l3.png", "r3.png"]])}
    sec = stereo_section("stereo/cam0_cam1", arrays, {})
    figs = [it for it in sec.items if hasattr(it, "savefig")]
    assert len(figs) == 2
    bars = figs[0].axes[0].patches
    assert np.allclose([b.get_height() for b in bars], [0.1, 0.2, 0.3])
    assert [t.get_text() for t in figs[0].axes[0].get_xticklabels()] == ["l1.png / r1.png", "l2.png / r2.png", "l3.png / r3.png"]


def test_lidar_camera_section_reads_files_named_by_the_session(tmp_path, capsys):
    import cv2

    from radarcal.io import write_pcd
    from radarcal.report.build import build_report
    from radarcal.bundle import load_bundle

    rng = np.random.default_rng(5)
    pts = np.c_[rng.uniform(3, 20, 3000), rng.uniform(-4, 4, 3000), rng.uniform(-1, 2, 3000)].astype(np.float32)
    write_pcd(tmp_path / "cloud.pcd", pts)
    cv2.imwrite(str(tmp_path / "img.png"), np.full((1024, 1280, 3), 90, np.uint8))
    b = Bundle(path=tmp_path / "calib.yaml")
    b.set_camera("cam0", CAM)
    b.set_transform("cam0", "lidar0", T_CAM_LIDAR, method="edges")
    LidarCameraSession(T_final=T_CAM_LIDAR, camera="cam0", lidar="lidar0", pairs=[["img.png", "cloud.pcd"]]).save(b, "lidar_camera/cam0_lidar0")
    save_bundle(b, b.path)
    content = build_report(load_bundle(b.path))
    sec = content.sections[-1]
    figs = [it for it in sec.items if hasattr(it, "savefig")]
    assert len(figs) == 1  # the overlay; matches, histogram and profiles are reported missing
    ax = figs[0].axes[0]
    uv, valid, _ = CAM.project_from(T_CAM_LIDAR, pts.astype(float))
    assert len(ax.collections[0].get_offsets()) == int((valid & CAM.in_image(uv)).sum())
    assert len(ax.images) == 1  # the image named by the session is drawn underneath
    assert sum("skipped" in k for k in content.skipped) == 3


def test_lidar_camera_section_of_the_command_layout(bundle_path):
    from radarcal.bundle import load_bundle, load_session
    from radarcal.io import read_cloud
    from radarcal.report.build import lidar_camera_section

    b = load_bundle(bundle_path)
    arrays, meta = load_session(b, "lidar_camera/cam0_lidar0")
    import cv2

    img = cv2.imread(str(bundle_path.parent / "scene.png"))
    pts = read_cloud(bundle_path.parent / "cloud.pcd").points
    sec = lidar_camera_section("lidar_camera/cam0_lidar0", CAM, arrays, meta, None, img, None, b.transforms["T_cam0_lidar0"].sigma, points_lidar=pts)
    figs = [it for it in sec.items if hasattr(it, "savefig")]
    assert len(figs) == 4
    overlay = figs[0]
    assert [ax.get_title().split(":")[0] for ax in overlay.axes[:2]] == ["before", "after"]
    assert len(overlay.axes[0].images) == 1
    uv, valid, _ = CAM.project_from(T_CAM_LIDAR, pts.astype(float))
    assert len(overlay.axes[1].collections[0].get_offsets()) == int((valid & CAM.in_image(uv)).sum())
    matches = figs[1].axes[0].collections[0]
    assert np.allclose(np.asarray(matches.get_segments())[:, 0], arrays["scene0_uv"])
    assert np.allclose(matches.get_array(), np.abs(arrays["residuals_after"]))
    tables = [it for it in sec.items if isinstance(it, Table)]
    assert tables and tables[0].rows[0][:2] == ["rx", "0.05"] and tables[0].rows[5][:2] == ["tz", "0.002"]
    assert sec.items[0].startswith("method: edge-alignment; converged")

"""Files named in session files: stored relative to the session file's folder, found from any working folder and
after the project folder moved; figures that need an image say so when it is missing."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from radarcal.bundle import Bundle, load_bundle, load_session, save_bundle
from radarcal.cli.main import main as cli
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.intrinsics.session import IntrinsicsSession
from radarcal.io import write_pcd
from radarcal.pnp.session import FieldPnPSession
from tests.report.test_report_cli import CAM, T_CAM_LIDAR, _intrinsics_session


def _project(root, image_for_field: bool = True):
    """A project folder as the commands leave it: data in sub-folders named on the command line (here as absolute
    paths), the bundle and its sessions beside them."""
    rng = np.random.default_rng(1)
    (root / "images").mkdir(parents=True)
    (root / "clouds").mkdir()
    for i in range(12):
        cv2.imwrite(str(root / "images" / f"img{i:02d}.png"), np.full((1024, 1280), 50 + 10 * i, np.uint8))
    cv2.imwrite(str(root / "images" / "scene.png"), np.full((1024, 1280, 3), 100, np.uint8))
    write_pcd(root / "clouds" / "cloud.pcd", np.c_[rng.uniform(3, 20, 3000), rng.uniform(-4, 4, 3000), rng.uniform(-1, 2, 3000)])
    b = Bundle(path=root / "calib.yaml")
    b.set_camera("cam0", CAM, rms_px=0.2)
    b.set_transform("cam0", "lidar0", T_CAM_LIDAR, method="edges")
    s = _intrinsics_session(rng)
    s.names = np.array([str(root / "images" / f"img{i:02d}.png") for i in range(12)])
    s.save(b, "intrinsics/cam0")
    LidarCameraSession(T_final=T_CAM_LIDAR, camera="cam0", lidar="lidar0", pairs=[[str(root / "images" / "scene.png"), str(root / "clouds" / "cloud.pcd")]]).save(b, "lidar_camera/cam0_lidar0")
    picked = np.array([[100.0, 800], [1200, 300], [640, 400], [300, 900]])
    FieldPnPSession(names=np.array(["a", "b", "c", "d"]), uv=picked, residuals_px=np.full((4, 2), 0.5), camera="cam0",
                    image=str(root / "images" / "scene.png") if image_for_field else "").save(b, "field_pnp/cam0")  # fmt: skip
    b.field_model = {"name": "test", "size": [28.0, 15.0], "landmarks": {"a": [0, 0, 0], "b": [28, 15, 0], "c": [14, 7.5, 0.6], "d": [10, 2, 0]}}
    save_bundle(b, b.path)
    return b.path


def _report(bundle_path, out, *extra):
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli(["report", str(bundle_path), "-o", str(out), "--dpi", "30", "--json", *extra]) == 0
    s = json.loads(buf.getvalue())
    return s


def _figure_titles(html: str) -> list[str]:
    """The titles of the page's figures (their alt text), in order."""
    import re

    return re.findall(r'<img alt="([^"]*)"', html)


def test_paths_stored_relative_to_the_session_file(tmp_path):
    p = _project(tmp_path / "proj")
    b = load_bundle(p)
    _, meta = load_session(b, "lidar_camera/cam0_lidar0")
    assert meta["pairs"] == [["../images/scene.png", "../clouds/cloud.pcd"]]
    arrays, meta = load_session(b, "field_pnp/cam0")
    assert meta["image"] == "../images/scene.png"
    arrays, _ = load_session(b, "intrinsics/cam0")
    assert list(arrays["names"][:2]) == ["../images/img00.png", "../images/img01.png"]


def test_cwd_relative_names_are_stored_relative_to_the_session(tmp_path, monkeypatch):
    """A command run inside the project with relative file names (the usual case) stores them for the session."""
    (tmp_path / "p" / "data").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "p" / "data" / "f.png"), np.zeros((8, 8), np.uint8))
    monkeypatch.chdir(tmp_path / "p")
    b = Bundle(path=tmp_path / "p" / "out" / "calib.yaml")
    (tmp_path / "p" / "out").mkdir()
    FieldPnPSession(image="data/f.png", picks_file="data/f.png").save(b, "field_pnp/cam0")
    _, meta = load_session(b, "field_pnp/cam0")
    assert meta["image"] == "../../data/f.png"  # from out/calib.sessions/
    assert meta["picks_file"] == "data/f.png"  # not a PATH_FIELD: kept as given
    LidarCameraSession(pairs=[["data/f.png", "gone.pcd"]]).save(b, "lidar_camera/cam0_lidar0")
    assert load_session(b, "lidar_camera/cam0_lidar0")[1]["pairs"] == [["../../data/f.png", "gone.pcd"]]  # a missing file: as given


def test_moved_project_renders_the_same_figures(tmp_path, monkeypatch):
    p = _project(tmp_path / "proj")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # run from another folder
    first = _report(p, tmp_path / "r1.html")
    assert not [k for k in first["skipped"] if "without the image" in k or "cloud points" in k or "not found" in k], first["skipped"]  # every named file found
    html1 = (tmp_path / "r1.html").read_text()
    assert "Residual vectors on the worst kept view" in html1  # the intrinsics view image found
    # move the whole project; the absolute paths the commands were given no longer exist
    shutil.move(str(tmp_path / "proj"), tmp_path / "moved")
    assert not (tmp_path / "proj").exists()
    second = _report(tmp_path / "moved" / "calib.yaml", tmp_path / "r2.html")
    assert second["skipped"] == first["skipped"] and second["figures"] == first["figures"] and second["sections"] == first["sections"]
    assert _figure_titles((tmp_path / "r2.html").read_text()) == _figure_titles(html1)
    # the session folder alone moved elsewhere, found with --session: the data next to the bundle is still found
    shutil.move(str(tmp_path / "moved" / "calib.sessions"), tmp_path / "sessions_copy")
    third = _report(tmp_path / "moved" / "calib.yaml", tmp_path / "r3.html", "--session", str(tmp_path / "sessions_copy"))
    assert third["skipped"] == first["skipped"] and third["figures"] == first["figures"]


def test_overlay_and_image_figures_from_the_moved_project(tmp_path, monkeypatch):
    """The LiDAR overlay and the field picks are drawn over the images named by the sessions after the move."""
    from radarcal.report.build import build_report

    p = _project(tmp_path / "proj")
    shutil.move(str(tmp_path / "proj"), tmp_path / "moved")
    monkeypatch.chdir(tmp_path)
    content = build_report(load_bundle(tmp_path / "moved" / "calib.yaml"))
    lc = next(s for s in content.sections if s.title.startswith("LiDAR-camera"))
    fp = next(s for s in content.sections if s.title.startswith("Field pose"))
    overlay = next(it for it in lc.items if hasattr(it, "savefig"))
    assert len(overlay.axes[0].images) == 1 and len(overlay.axes[0].collections[0].get_offsets()) > 100
    picks = [it for it in fp.items if hasattr(it, "savefig")][-1]
    assert len(picks.axes[0].images) == 1
    assert p.name == "calib.yaml"


@pytest.mark.parametrize("missing", ["named but gone", "not named"])
def test_picks_without_their_image_say_so(tmp_path, missing):
    from radarcal.report.build import build_report

    p = _project(tmp_path / "proj", image_for_field=missing == "named but gone")
    (tmp_path / "proj" / "images" / "scene.png").unlink()
    content = build_report(load_bundle(p))
    fp = next(s for s in content.sections if s.title.startswith("Field pose"))
    picks = [it for it in fp.items if hasattr(it, "savefig")][-1]
    assert len(picks.axes[0].images) == 0  # drawn on the image's extent, no image under it
    why = "../images/scene.png not found" if missing == "named but gone" else "the session names no image"
    assert any(k.startswith("Field pose: cam0: picks and residuals drawn without the image") and why in k for k in content.skipped), content.skipped
    assert any(isinstance(it, str) and why in it for it in fp.items)
    assert any(k.startswith("LiDAR-camera: cam0_lidar0: LiDAR-camera figures drawn without the image") for k in content.skipped)


def test_worst_view_falls_back_to_a_view_whose_image_exists(tmp_path):
    from radarcal.report.build import build_report

    p = _project(tmp_path / "proj")
    arrays, _ = load_session(load_bundle(p), "intrinsics/cam0")
    err = np.where(arrays["view_used"], arrays["view_rms_px"], -1)
    worst, second = np.argsort(-err)[:2]
    (tmp_path / "proj" / "images" / f"img{worst:02d}.png").unlink()
    content = build_report(load_bundle(p))
    sec = next(s for s in content.sections if s.title.startswith("Intrinsics"))
    titles = [it.axes[0].get_title() for it in sec.items if hasattr(it, "savefig")]
    assert any(f"worst kept view with its image on disk (1 worse without), img{second:02d}.png" in t for t in titles), titles
    assert any(f"img{worst:02d}.png (the worst kept view) drawn over img{second:02d}.png" in k for k in content.skipped)
    for f in (tmp_path / "proj" / "images").glob("img*.png"):
        f.unlink()
    content = build_report(load_bundle(p))
    assert any("residual vectors over a view's image skipped" in k for k in content.skipped)


def test_intrinsics_session_relative_names_keep_their_labels(tmp_path):
    p = _project(tmp_path / "proj")
    from radarcal.report.build import build_report

    sec = next(s for s in build_report(load_bundle(p)).sections if s.title.startswith("Intrinsics"))
    per_view = next(it for it in sec.items if hasattr(it, "savefig"))
    assert [t.get_text() for t in per_view.axes[0].get_xticklabels()][:2] == ["img00.png", "img01.png"]
    assert IntrinsicsSession.KIND == "intrinsics"

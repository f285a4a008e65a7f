"""The radar(-LiDAR) section of `radarcal report`: a generated radar session (`radarcal synth radar`) calibrated by
`radarcal radar-lidar`, then reported; every figure carries the session's and the bundle's own values."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle, load_session
from radarcal.cli.main import main
from radarcal.extrinsics.radar_lidar_session import RadarLidarSession

RADARS = ["radar_left", "radar_middle", "radar_right"]


@pytest.fixture(scope="module")
def radar_bundle(tmp_path_factory):
    d = tmp_path_factory.mktemp("radar")
    ses = d / "session"
    assert main(["synth", "radar", str(ses), "--seed", "5", "--frames", "10", "--ghosts", "0.5", "--extra-lidars", "1"]) == 0
    assert main(["radar-lidar", str(ses), "--bundle", str(d / "b.yaml")]) == 0
    return d / "b.yaml", json.loads((ses / "truth.json").read_text())


def _section(bundle_path):
    from radarcal.report.build import build_report

    content = build_report(load_bundle(bundle_path))
    secs = [s for s in content.sections if s.title.startswith("Radar-LiDAR")]
    assert len(secs) == 1
    return secs[0], content


def _figures(sec):
    return [it[0] if isinstance(it, tuple) else it for it in sec.items if hasattr(it[0] if isinstance(it, tuple) else it, "savefig")]


def test_radar_session_report_has_figures(radar_bundle, tmp_path, capsys):
    bundle_path, _ = radar_bundle
    capsys.readouterr()
    assert main(["report", str(bundle_path), "-o", str(tmp_path / "r.html"), "--dpi", "40", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["sections"] == ["Bundle overview", "Radar-LiDAR: lidar_front"]
    assert s["figures"] == 4 and s["skipped"] == []  # residuals, top view, RCS/range, pose sigma


def test_radar_figures_show_the_session_values(radar_bundle):
    bundle_path, truth = radar_bundle
    b = load_bundle(bundle_path)
    rec = RadarLidarSession.load(b, "radar_lidar")
    assert rec.radars() == RADARS and rec.main_lidar == "lidar_front"
    sec, _ = _section(bundle_path)
    resid, top, rcs, sigma = _figures(sec)

    # residual per reflector: one bar per matched reflector, height = the session's residual in cm, in radar order
    heights = [p.get_height() for p in resid.axes[0].patches]
    want = np.concatenate([rec.reflectors(r)["residual_m"][rec.reflectors(r)["used"]] * 100 for r in RADARS])
    np.testing.assert_allclose(heights, want, rtol=1e-12)
    labels = [t.get_text() for t in resid.axes[0].get_xticklabels()]
    r0 = rec.reflectors(RADARS[0])
    assert labels[0] == f"{r0['scene'][0]} #{r0['lidar_index'][0]}"
    # the legend names each radar's RMS, equal to the bundle entry's rms_m
    legend = [t.get_text() for t in resid.axes[0].get_legend().get_texts()]
    for r in RADARS:
        rms = b.transforms[f"T_lidar_front_{r}"].residual["rms_m"] * 100
        assert any(t.startswith(f"{r}: RMS {rms:.2f} cm") for t in legend), (r, legend)

    # top view: reflectors = the session's LiDAR centres; matched detections = radar xy through the bundle's T
    ax = top.axes[0]
    by_label = {ln.get_label(): np.c_[ln.get_xdata(), ln.get_ydata()] for ln in ax.lines}
    centres = np.concatenate([rec.lidar_centres(s) for s in rec.scenes()])
    np.testing.assert_allclose(by_label["reflector (lidar_front)"], centres[:, :2])
    for r in RADARS:
        xy = np.concatenate([rec.radar_xy(s, r) for s in rec.scenes()])
        lab = np.array([x for s in rec.scenes() for x in rec.detections[s][r]])
        matched = np.char.startswith(lab.astype(str), "reflector")
        p_main = geometry.transform_points(b.T("lidar_front", r), np.c_[xy, np.zeros(len(xy))])
        np.testing.assert_allclose(by_label[f"{r}: matched reflector"], p_main[matched, :2], atol=1e-9)
        # held-out truth: the same detections through the true pose land within 2 cm of where the report draws them
        p_true = geometry.transform_points(np.array(truth["T_main_sensor"][r]), np.c_[xy, np.zeros(len(xy))])
        assert np.abs(p_true[matched, :2] - p_main[matched, :2]).max() < 0.02

    # RCS against range: x = |xy| (slant range as measured), y = the stored RCS
    ax = rcs.axes[0]
    pts = {ln.get_label(): np.c_[ln.get_xdata(), ln.get_ydata()] for ln in ax.lines}
    r = RADARS[1]
    xy = np.concatenate([rec.radar_xy(s, r) for s in rec.scenes()])
    c = np.concatenate([rec.rcs(s, r) for s in rec.scenes()])
    lab = np.array([x for s in rec.scenes() for x in rec.detections[s][r]]).astype(str)
    m = np.char.startswith(lab, "reflector")
    np.testing.assert_allclose(pts[f"{r}: matched reflector"], np.c_[np.hypot(*xy[m].T), c[m]])
    # the synthetic reflectors are strong, the ghosts weak: the figure shows them apart
    ghosts = pts.get(f"{r}: unmatched (ghost)")
    assert ghosts is not None and ghosts[:, 1].max() < pts[f"{r}: matched reflector"][:, 1].min()

    # pose sigma: yaw bars = the bundle's sigma.yaw_deg, x/y bars = sigma x_m / y_m in cm
    yaw_bars = [p.get_height() for p in sigma.axes[0].patches][: len(RADARS)]
    names = [t.get_text() for t in sigma.axes[0].get_xticklabels()]
    np.testing.assert_allclose(yaw_bars, [b.transforms[f"T_lidar_front_{n}"].sigma["yaw_deg"] for n in names])
    xy_bars = [p.get_height() for p in sigma.axes[1].patches]
    np.testing.assert_allclose(xy_bars[: len(names)], [b.transforms[f"T_lidar_front_{n}"].sigma["x_m"] * 100 for n in names])

    # tables: the radar table row of radar_middle shows its RMS and sigma from the bundle; the LiDAR-LiDAR row exists
    from radarcal.report.html import Table

    tables = [it for it in sec.items if isinstance(it, Table)]
    row = next(rw for t in tables for rw in t.rows if rw[0] == "T_lidar_front_radar_middle")
    e = b.transforms["T_lidar_front_radar_middle"]
    assert row[1] == f"{e.residual['rms_m'] * 100:.2f}" and row[5] == f"{e.sigma['yaw_deg']:.3f}"
    assert any(rw[0] == "T_lidar_front_lidar_left" for t in tables for rw in t.rows)


def test_radar_session_without_rcs_or_poses_says_what_is_missing(radar_bundle, tmp_path):
    """A session written before RCS was stored (and a bundle without one radar's pose): the figures it allows, and
    notes for the rest."""
    from radarcal.bundle import save_bundle, save_session
    from radarcal.report.build import build_report

    bundle_path, _ = radar_bundle
    b = load_bundle(bundle_path)
    arrays, meta = load_session(b, "radar_lidar")
    arrays = {k: v for k, v in arrays.items() if "/rcs/" not in k}
    b.path = tmp_path / "old.yaml"
    del b.transforms["T_lidar_front_radar_right"]
    save_session(b, "radar_lidar", arrays, {k: v for k, v in meta.items() if k != "kind"})
    save_bundle(b, b.path)
    content = build_report(load_bundle(b.path))
    sec = content.sections[-1]
    assert len(_figures(sec)) == 3  # residuals, top view (two radars), sigma
    assert any("RCS against range skipped" in k for k in content.skipped)
    assert any("top view without radar_right" in k for k in content.skipped)


def test_report_imports_no_solver():
    """Importing the report (and building its radar section) pulls in no solver module."""
    code = ("import sys, radarcal.report, radarcal.report.build, radarcal.report.make, radarcal.verdicts; "
            "pk = ('radarcal.extrinsics', 'radarcal.intrinsics', 'radarcal.pnp'); "
            "bad = [m for m in sys.modules if m.startswith(tuple(p + '.' for p in pk)) and not m.endswith(('session', '.pose_params'))]; print(bad)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", out

"""`radarcal field-pnp` end to end on a generated replay's calib.yaml: bundle entries, session, PNG, exit codes."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle, load_session
from radarcal.cli.main import main
from radarcal.field import load_field
from radarcal.synth.field import FieldSceneConfig, write_field_replay

RED4 = ["blue_base", "blue_outpost", "red_outpost", "central_highland_red_south"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    write_field_replay(out, load_field("rmuc2024"), FieldSceneConfig(frames=1, seed=2, robots=2, lidar_points=300, image_scale=0.1))
    return out, json.loads((out / "truth.json").read_text())


@pytest.fixture
def work(scene, tmp_path):
    out, truth = scene
    b = tmp_path / "calib.yaml"
    shutil.copy(out / "calib.yaml", b)
    return b, truth, tmp_path


def _write_picks(path, truth, names, offsets=None):
    rows = ["name,u,v"]
    for i, n in enumerate(names):
        u, v = truth["landmark_pixels"][n]
        du, dv = (offsets or {}).get(n, (0.0, 0.0))
        rows.append(f"{n},{u + du!r},{v + dv!r}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_exact_picks_write_pose_chain_session_png(work, capsys):
    b, truth, tmp = work
    picks = _write_picks(tmp / "picks.csv", truth, RED4)
    png = tmp / "map.png"
    code = main(["field-pnp", "--bundle", str(b), "--camera", "cam0", "--field", "rmuc2024", "--points", str(picks), "--error-map", str(png), "--json"])
    out = capsys.readouterr().out
    assert code == 0
    s = json.loads(out)
    assert s["rms_px"] < 1e-6 and s["depth_source"] == "lidar" and s["lidar"] == "lidar0"
    assert s["error_map"]["lidar"]["median_m"] < s["error_map"]["ground"]["median_m"]
    bd = load_bundle(b)
    T_true = geometry.invert_T(np.asarray(truth["T_field_cam0"]))
    assert "T_cam0_field" in bd.transforms and "T_field_cam0" not in bd.transforms
    deg, m = geometry.pose_error(bd.T("cam0", "field"), T_true)
    assert deg < 1e-6 and m < 1e-6
    deg, m = geometry.pose_error(bd.T("field", "lidar0"), np.asarray(truth["T_field_lidar0"]))
    assert deg < 1e-6 and m < 1e-6
    e = bd.transforms["T_cam0_field"]
    assert set(e.residual["per_point_px"]) == set(RED4) and len(e.sigma["camera_position_m"]) == 3
    assert bd.field_model["name"] == "rmuc_schematic"  # rmuc2024 is the old name of the schematic
    arrays, meta = load_session(bd, "field_pnp/cam0")
    assert list(arrays["names"]) == RED4 and arrays["sigma_lidar"].shape == (15, 28) and meta["depth_source"] == "lidar"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_human_output_and_ground_fallback(work, capsys):
    b, truth, tmp = work
    picks = _write_picks(tmp / "picks.csv", truth, RED4, {"blue_base": (0.7, -0.4), "red_outpost": (-0.5, 0.8)})
    bd = load_bundle(b)
    bd.transforms.pop("T_cam0_lidar0")
    from radarcal.bundle import save_bundle

    save_bundle(bd, b)
    code = main(["field-pnp", "-b", str(b), "--points", str(picks)])
    out = capsys.readouterr().out
    assert code == 0
    assert "ground-ray fallback" in out and "reprojection RMS" in out and "blue_base" in out and "ground fallback  median" in out


@pytest.mark.parametrize(
    "case, words",
    [
        ("unknown", "unknown landmark 'blue_tower'"),
        ("three", "at least 4 picks"),
        ("coincident", "same point clicked twice"),
        ("collinear", "collinear"),
        ("swapped", "order"),  # refused: implausible, or the plausible poses fit 180 px; the message asks about the order
        ("bad_pick", "above the threshold"),
        ("garbage", "line 2: expected name,u,v"),
        ("outside", "outside the 1280x1024 image"),
        ("missing", "picks file not found"),
    ],
)
def test_degenerate_inputs_exit_2_one_line(work, capsys, case, words):
    b, truth, tmp = work
    p = tmp / "picks.csv"
    _write_picks(p, truth, RED4)
    lines = p.read_text().splitlines()
    if case == "unknown":
        lines[1] = "blue_tower,100,200"
    elif case == "three":
        lines = lines[:4]
    elif case == "coincident":
        n, u, v = lines[2].split(",")
        n0, u0, v0 = lines[1].split(",")
        lines[2] = f"{n},{float(u0) + 0.3},{v0}"
    elif case == "collinear":
        lines = ["name,u,v"] + [f"{n},{100 + 200 * i},{100 + 200 * i}" for i, n in enumerate(RED4)]
    elif case == "swapped":
        a, c = lines[1].split(","), lines[2].split(",")
        lines[1], lines[2] = ",".join([a[0]] + c[1:]), ",".join([c[0]] + a[1:])
    elif case == "bad_pick":
        n, u, v = lines[4].split(",")
        lines[4] = f"{n},{u},{float(v) + 40}"
    elif case == "garbage":
        lines[1] = "blue_base 479 255"
    elif case == "outside":
        lines[1] = "blue_base,1500,200"
    if case == "missing":
        p = tmp / "nope.csv"
    else:
        p.write_text("\n".join(lines) + "\n")
    before = b.read_bytes()
    code = main(["field-pnp", "-b", str(b), "--points", str(p)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("error: ") and words in err and "\n" not in err, err
    assert b.read_bytes() == before  # nothing written


def test_headless_image_asks_for_points(work, capsys, monkeypatch, scene):
    b, truth, tmp = work
    monkeypatch.setenv("MPLBACKEND", "Agg")
    code = main(["field-pnp", "-b", str(b), "--image", str(scene[0] / "images" / "000000.jpg")])
    err = capsys.readouterr().err
    assert code == 2 and "pass --points" in err and "headless" in err


def test_unknown_field_and_camera(work, capsys):
    b, truth, tmp = work
    p = _write_picks(tmp / "picks.csv", truth, RED4)
    assert main(["field-pnp", "-b", str(b), "--points", str(p), "--field", "nofield.yaml"]) == 2
    assert "built-in: rmuc2024" in capsys.readouterr().err
    assert main(["field-pnp", "-b", str(b), "--points", str(p), "--camera", "cam9"]) == 2
    assert "no camera 'cam9'" in capsys.readouterr().err


def test_overlay_draws_landmarks_where_they_are(work, capsys, scene):
    b, truth, tmp = work
    picks = _write_picks(tmp / "picks.csv", truth, RED4)
    ov = tmp / "ov.png"
    img = scene[0] / "images" / "000000.jpg"
    assert main(["field-pnp", "-b", str(b), "--points", str(picks), "--image", str(img), "--overlay", str(ov)]) == 0
    import cv2

    a = cv2.imread(str(ov))
    assert a.shape == (1024, 1280, 3)
    u, v = (int(round(x)) for x in truth["landmark_pixels"]["blue_outpost"])
    assert a[v, u, 2] > 200 and a[v, u, 0] < 80  # the red cross of the projected landmark sits on its true pixel
    assert main(["field-pnp", "-b", str(b), "--points", str(picks), "--overlay", str(ov)]) == 2
    assert "needs --image" in capsys.readouterr().err

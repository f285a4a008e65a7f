"""``radarcal synth field --cameras``: several cameras over one scene, truth consistent with what each camera sees."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal.bundle import load_bundle
from radarcal.field import load_field
from radarcal.geometry import invert_T
from radarcal.synth.field import FieldSceneConfig
from radarcal.synth.field_cameras import MultiCameraConfig, camera_rigs, detector_model, parse_camera_specs, write_multicam_replay


def test_parse_camera_specs():
    a, b = parse_camera_specs("cam0=6mm,cam1=16mm:4024x3036@21:6.5")
    assert (a.name, a.focal_mm, a.size, a.aim) == ("cam0", 6.0, (1280, 1024), None)
    assert (b.name, b.focal_mm, b.size, b.aim) == ("cam1", 16.0, (4024, 3036), (21.0, 6.5))
    for bad in ("cam0", "cam0=6", "cam0=6mm,cam0=8mm", "cam0=500mm", ""):
        with pytest.raises(ValueError):
            parse_camera_specs(bad)


def test_rigs_aim_and_share_the_lidar():
    fm = load_field("rmuc2024")
    rigs, T_field_lidar = camera_rigs(fm, parse_camera_specs("cam0=6mm,cam1=16mm@21:6"), np.random.default_rng(0))
    tele = rigs["cam1"]
    assert tele.camera.fx == pytest.approx(16 / 0.0048)
    # the tele's optical axis passes through its aim point on the ground
    uv, ok, _ = tele.camera.project_from(invert_T(tele.T_field_cam), np.array([[21.0, 6.0, 0.0]]))
    assert ok[0] and np.allclose(uv[0], tele.camera.K[:2, 2], atol=1e-6)
    for r in rigs.values():  # one LiDAR: every camera's T_field_cam @ T_cam_lidar is the same T_field_lidar
        assert np.allclose(r.T_field_cam @ r.T_cam_lidar, T_field_lidar, atol=1e-9)
    m = detector_model(np.array([5.0, 20.0, 100.0]))
    assert m["miss"][0] == 1.0 and m["miss"][2] == pytest.approx(0.03) and m["misread"][1] > 0.3 > 0.02 > m["misread"][2]


def test_multicam_replay_truth(tmp_path):
    fm = load_field("rmuc2024")
    cfg = FieldSceneConfig(frames=20, seed=3, robots=4, image_scale=0.1, image_every=20, lidar_points=2000)
    s = write_multicam_replay(tmp_path, fm, MultiCameraConfig(cfg, parse_camera_specs("cam0=6mm,cam1=16mm"), gaps={"cam1": (0.3, 10.0)}))
    assert s["cameras"] == ["cam0", "cam1"] and s["clouds"] == 6
    b = load_bundle(tmp_path / "calib.yaml")
    assert set(b.cameras) == {"cam0", "cam1"} and b.has_T("cam1", "lidar0") and b.has_T("field", "cam1")
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["cameras"] == ["cam0", "cam1"]
    truth = {json.loads(x)["frame"]: json.loads(x) for x in (tmp_path / "truth.jsonl").read_text().splitlines()}
    assert len(truth) == 40 and truth["cam1/000000.jpg"]["t"] == pytest.approx(0.011)
    heights = {}
    for cam in ("cam0", "cam1"):
        lines = [json.loads(x) for x in (tmp_path / "cameras" / cam / "detections.jsonl").read_text().splitlines()]
        # cam1 is unplugged from 0.3 s on: its frames stop there (frame times 0.011 + k/30)
        assert len(lines) == (20 if cam == "cam0" else 9)
        rig_cam, T_field_cam = b.camera(cam), b.T("field", cam)
        for ln in lines:
            tr = truth[f"{cam}/{ln['frame']}"]
            assert ln["t"] == pytest.approx(tr["t"])
            for box in ln["boxes"]:
                colour = box["label"].split("_")[0]
                # each box is around a true robot of its colour that this camera sees (its number may be misread)
                cands = [r for r in tr["robots"] if r["label"].startswith(colour) and cam in r["visible_in"]]
                uv, ok, _ = rig_cam.project_from(invert_T(T_field_cam), np.array([np.add(r["p_field"], [0, 0, 0.25]) for r in cands]))
                x1, y1, x2, y2 = box["xyxy"]
                pad = 0.5 * (x2 - x1) + 3
                assert any(o and x1 - pad <= u <= x2 + pad and y1 - pad <= v <= y2 + pad for (u, v), o in zip(uv, ok)), (cam, ln["frame"], box)
                heights.setdefault(cam, []).append(y2 - y1)
    assert np.median(heights["cam1"]) > 1.8 * np.median(heights["cam0"])  # the tele sees its robots larger

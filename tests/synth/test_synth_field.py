"""`radarcal synth field`: LiDAR points on the objects they hit, true image boxes, landmark pixels, determinism."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from radarcal import geometry
from radarcal.bundle import load_bundle
from radarcal.field import load_field
from radarcal.io import read_cloud, read_image
from radarcal.synth.field import (
    FieldSceneConfig,
    box_corners,
    default_rig,
    make_robots,
    object_kinds,
    raycast,
    robot_states,
    scene_boxes,
    simulate_lidar,
    write_field_replay,
)


@pytest.fixture(scope="module")
def fm():
    return load_field("rmuc2024")


@pytest.fixture(scope="module")
def replay(tmp_path_factory, fm):
    out = tmp_path_factory.mktemp("replay")
    cfg = FieldSceneConfig(frames=16, seed=7, robots=8, lidar_points=4000, image_scale=0.35, lidar_gap=(0.2, 0.2))
    summary = write_field_replay(out, fm, cfg)
    return out, summary


def _scene_at(fm, seed=5, n=8, t=2.0):
    rng = np.random.default_rng(seed)
    rig = default_rig(fm, rng)
    robots = make_robots(fm, n, rng)
    p, yaw = robot_states(fm, robots, t)
    return rig, robots, scene_boxes(fm, robots, p[0], yaw[0])


def _in_box(p, c, size, yaw, tol):
    cy, sy = np.cos(yaw), np.sin(yaw)
    r = p - c
    x = cy * r[:, 0] + sy * r[:, 1]
    y = -sy * r[:, 0] + cy * r[:, 1]
    return (np.abs(x) <= size[0] / 2 + tol) & (np.abs(y) <= size[1] / 2 + tol) & (r[:, 2] >= -tol) & (r[:, 2] <= size[2] + tol)


def test_lidar_points_lie_on_the_objects_they_hit(fm):
    rig, robots, boxes = _scene_at(fm)
    pts, inten, obj, rng_true = simulate_lidar(fm, boxes, rig.T_field_lidar, 0.0, 20000, np.random.default_rng(0), range_sigma=0.0)
    assert len(pts) > 15000  # most of the 70.4° cone looks down at the field
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), rng_true, rtol=1e-6)
    p = geometry.transform_points(rig.T_field_lidar, pts.astype(float))
    kinds = object_kinds(fm, boxes)
    A = len(fm.areas)
    ground = obj == 0
    np.testing.assert_allclose(p[ground, 2], 0.0, atol=1e-4)
    for j in range(A):  # on area j's top or on one of its walls (inside its polygon's closure, below the top)
        m = obj == j + 1
        if m.any():
            from radarcal.field import _area_top

            assert np.all(p[m, 2] <= _area_top(fm.areas[j], p[m, :2]) + 1e-4) and np.all(p[m, 2] >= -1e-4)
    hit_boxes = 0
    for k in range(len(boxes)):
        m = obj == A + 1 + k
        if m.any():
            hit_boxes += kinds[A + 1 + k] == "robot"
            assert np.all(_in_box(p[m], boxes.center[k], boxes.size[k], boxes.yaw[k], 1e-4))
            # ... and on its surface, not inside it
            assert not np.any(_in_box(p[m], boxes.center[k], boxes.size[k], boxes.yaw[k], -1e-3))
    assert hit_boxes >= 3
    # the Livox rosette covers a 70.4° circular FOV and never leaves it
    ang = np.degrees(np.arccos(np.clip(pts[:, 0] / np.linalg.norm(pts, axis=1), -1, 1)))
    assert ang.max() <= 35.2 + 1e-3 and ang.max() > 34.0


def test_lidar_and_camera_agree_on_object_ids(fm):
    """LiDAR points projected with the true T_cam_lidar land on the object the camera ray sees (≥ 99 %)."""
    rig, robots, boxes = _scene_at(fm, seed=11)
    pts, _, obj, _ = simulate_lidar(fm, boxes, rig.T_field_lidar, 0.3, 20000, np.random.default_rng(1), range_sigma=0.0)
    uv, valid, _ = rig.camera.project_from(rig.T_cam_lidar, pts.astype(float))
    ok = valid & rig.camera.in_image(uv)
    rays_c = rig.camera.unproject(uv[ok])
    t, obj_cam = raycast(fm, boxes, rig.T_field_cam[:3, 3][None], rays_c @ rig.T_field_cam[:3, :3].T)
    agree = np.mean(obj_cam == obj[ok])
    assert ok.sum() > 5000 and agree >= 0.99, agree


def test_replay_files_load_and_match_truth(replay, fm):
    out, summary = replay
    meta = json.loads((out / "meta.json").read_text())
    truth = json.loads((out / "truth.json").read_text())
    assert meta["n_frames"] == 16 and meta["fps"] == 30 and meta["lidar_hz"] == 10 and meta["field"] == "rmuc_schematic"
    b = load_bundle(out / "calib.yaml")
    np.testing.assert_allclose(b.T("field", "lidar0"), np.asarray(truth["T_field_lidar0"]), atol=1e-12)
    assert b.field_model["name"] == "rmuc_schematic" and "red_outpost" in b.field_model["landmarks"]
    cam = b.camera("cam0")
    assert cam.image_size == (1280, 1024)
    # landmark true pixels agree with OpenCV's projection of the field coordinates
    T_cam_field = geometry.invert_T(np.asarray(truth["T_field_cam0"]))
    names = sorted(truth["landmark_pixels"])
    assert {"red_outpost", "blue_outpost", "blue_base"} <= set(names) and len(names) >= 8
    P = np.array([truth["landmarks_field"][n] for n in names])
    rvec, _ = cv2.Rodrigues(T_cam_field[:3, :3])
    uv_cv, _ = cv2.projectPoints(P, rvec, T_cam_field[:3, 3], cam.K, cam.dist)
    np.testing.assert_allclose(np.array([truth["landmark_pixels"][n] for n in names]), uv_cv.reshape(-1, 2), atol=1e-6)
    # images: full camera size; clouds: readable, gap respected
    img = read_image(out / "images" / "000000.jpg")
    assert img.shape == (1024, 1280, 3)
    times = [line.split(",") for line in (out / "clouds" / "times.csv").read_text().split()[1:]]
    ts = np.array([float(t) for _, t in times])
    assert not np.any((ts >= 0.2) & (ts < 0.4)) and len(ts) == 3  # 16 frames = 0.53 s -> clouds at 0, 0.1, 0.4, 0.5 minus ...
    cloud = read_cloud(out / "clouds" / times[0][0])
    assert cloud.points.shape[0] > 3000 and cloud.intensity is not None
    o3d = pytest.importorskip("open3d")
    t = o3d.t.io.read_point_cloud(str(out / "clouds" / times[0][0]))
    np.testing.assert_array_equal(t.point.positions.numpy(), cloud.points)
    np.testing.assert_array_equal(t.point.intensity.numpy().ravel(), cloud.intensity)


def test_clouds_on_disk_hit_ground_or_robots(replay, fm):
    """Written clouds, mapped with the bundle's T_field_lidar0: each point on the surface or on a robot/structure."""
    out, _ = replay
    b = load_bundle(out / "calib.yaml")
    T = b.T("field", "lidar0")
    truth_lines = [json.loads(s) for s in (out / "truth.jsonl").read_text().splitlines()]
    cloud = read_cloud(out / "clouds" / "000000.pcd")
    p = geometry.transform_points(T, cloud.points.astype(float))
    on = np.abs(p[:, 2] - fm.surface_z(p[:, :2])) < 0.1
    near_wall = np.zeros(len(p), bool)  # points on the walls of raised areas: near an edge, below its top
    for a in fm.areas:
        q0 = a["polygon"]
        e = np.roll(q0, -1, axis=0) - q0
        rel = p[:, None, :2] - q0[None]
        s = np.clip(np.sum(rel * e[None], -1) / np.sum(e * e, -1)[None], 0, 1)
        dist = np.linalg.norm(rel - s[..., None] * e[None], axis=-1).min(1)
        near_wall |= (dist < 0.1) & (p[:, 2] < a["z"] + 0.4) & (p[:, 2] > -0.1)
    robots = truth_lines[0]["robots"]  # cloud 0 and camera frame 0 share t = 0
    specs = {r["id"]: r["size_lwh"] for r in json.loads((out / "truth.json").read_text())["robots"]}
    for r in robots:
        on |= _in_box(p, np.array(r["p_field"]), np.array(specs[r["id"]]), r["yaw"], 0.1)
    for s in fm.structures:
        on |= _in_box(p, np.array(s["center"]), np.array(s["size"]), s["yaw"], 0.1)
    assert np.mean(on | near_wall) > 0.995


def test_true_boxes_contain_projected_robots(replay):
    out, _ = replay
    truth = json.loads((out / "truth.json").read_text())
    b = load_bundle(out / "calib.yaml")
    cam = b.camera("cam0")
    T_cam_field = b.T("cam0", "field")
    specs = {r["id"]: np.array(r["size_lwh"]) for r in truth["robots"]}
    dets = [json.loads(s) for s in (out / "detections.jsonl").read_text().splitlines()]
    checked = 0
    for f, line in enumerate((out / "truth.jsonl").read_text().splitlines()):
        rec = json.loads(line)
        assert rec["frame"] == f"{f:06d}.jpg" and abs(rec["t"] - f / 30) < 1e-6
        labels = {d["label"] for d in dets[f]["boxes"]}
        img = read_image(out / "images" / rec["frame"]).astype(int)
        for r in rec["robots"]:
            assert (r["id"] in labels) == r["visible"]  # no jitter / dropout configured
            if r["xyxy"] is None:
                continue
            x1, y1, x2, y2 = r["xyxy"]
            C = box_corners(np.array(r["p_field"]), specs[r["id"]], r["yaw"])
            uv, valid, _ = cam.project_from(T_cam_field, C)
            inside = cam.in_image(uv)
            assert np.all(uv[inside, 0] >= x1 - 0.01) and np.all(uv[inside, 0] <= x2 + 0.01)
            assert np.all(uv[inside, 1] >= y1 - 0.01) and np.all(uv[inside, 1] <= y2 + 0.01)
            if inside.all():  # tight: corners reach the box edges within 1 px (edges bulge a little with distortion)
                assert uv[:, 0].min() - x1 < 1.0 and x2 - uv[:, 0].max() < 1.0
                assert uv[:, 1].min() - y1 < 1.0 and y2 - uv[:, 1].max() < 1.0
                if r["visible"] and (x2 - x1) > 12:
                    # the rendered robot is there: its team colour dominates the box centre
                    cx, cy = int(round((x1 + x2) / 2)), int(round((y1 + y2) / 2))
                    patch = img[cy - 2 : cy + 3, cx - 2 : cx + 3].reshape(-1, 3).mean(0)  # BGR
                    blue_team = r["id"].startswith("blue")
                    checked += 1
                    assert (patch[0] > patch[2] + 30) if blue_team else (patch[2] > patch[0] + 30), (r, patch)
    assert checked >= 10


def test_deterministic_per_seed(tmp_path, fm):
    cfg = FieldSceneConfig(frames=4, seed=3, robots=4, lidar_points=1500, image_scale=0.2)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    write_field_replay(a, fm, cfg)
    write_field_replay(b, fm, cfg)
    write_field_replay(c, fm, FieldSceneConfig(frames=4, seed=4, robots=4, lidar_points=1500, image_scale=0.2))
    for rel in ("detections.jsonl", "truth.jsonl", "truth.json", "clouds/000000.pcd", "images/000003.jpg"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "truth.jsonl").read_bytes() != (c / "truth.jsonl").read_bytes()
    assert (a / "clouds/000000.pcd").read_bytes() != (c / "clouds/000000.pcd").read_bytes()


def test_cli_writes_replay_and_rejects_bad_options(tmp_path, capsys):
    from radarcal.cli.main import main

    out = tmp_path / "r"
    code = main(["synth", "field", str(out), "--frames", "3", "--robots", "2", "--lidar-points", "300", "--image-scale", "0.1", "--lidar-gap", "0:0.05", "--image-every", "2", "--json"])
    s = json.loads(capsys.readouterr().out)
    assert code == 0 and s["frames"] == 3 and s["images"] == 2 and s["clouds"] == 0  # 3 frames = 0.1 s -> one cloud at t = 0, in the gap
    assert (out / "meta.json").is_file() and len((out / "detections.jsonl").read_text().splitlines()) == 3
    assert sorted(p.name for p in (out / "images").glob("*.jpg")) == ["000000.jpg", "000002.jpg"]
    assert (out / "images" / "times.csv").read_text().split() == ["file,t", "000000.jpg,0.000000", "000002.jpg,0.066667"]
    assert main(["synth", "field", str(tmp_path / "x"), "--lidar-gap", "soon"]) == 2
    assert "--lidar-gap" in capsys.readouterr().err
    assert main(["synth", "field", str(tmp_path / "x"), "--robots", "20"]) == 2

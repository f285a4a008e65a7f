"""`radarcal synth lidar-camera` and `radarcal lidar-camera` end to end on a generated scene."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.cli.main import main


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("lc")
    assert main(["synth", "lidar-camera", "-o", str(out), "--seed", "4", "--duration", "3", "--boards", "0", "--json"]) == 0
    return out


def test_refine_cli_stores_transform_and_session(synth_dir, capsys):
    capsys.readouterr()
    ov = synth_dir / "ov.png"
    rc = main(["lidar-camera", "-b", str(synth_dir / "bundle.yaml"), "--image", str(synth_dir / "image.png"), "--cloud", str(synth_dir / "cloud.pcd"),
               "--init", str(synth_dir / "init.json"), "--refine", "--overlay", str(ov), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["stored"] and ov.is_file()
    assert out["intensity_edge_samples"][0] > 100  # the generated cloud has reflectivity: paint edges join the plane edges
    truth = json.loads((synth_dir / "truth.json").read_text())
    from radarcal.bundle import load_bundle, load_session

    b = load_bundle(synth_dir / "bundle.yaml")
    T = b.T("cam0", "lidar0")
    deg, m = geometry.pose_error(T, np.array(truth["T_cam_lidar"]))
    assert deg < 0.15 and m < 0.03
    e = b.transforms["T_cam0_lidar0"]
    assert "edge-alignment" in e.method and e.residual["edge_matches"] > 100 and len(e.sigma["edge_rot_deg"]) == 3
    arrays, meta = load_session(b, "lidar_camera/cam0_lidar0")
    assert {"residuals_before", "residuals_after", "profile_costs", "scene0_uv"} <= set(arrays) and arrays["profile_costs"].shape[0] == 6
    assert meta["converged"] is True and meta["kind"] == "lidar_camera" and meta["camera"] == "cam0"


def test_corners_cli(synth_dir, tmp_path, capsys):
    truth = json.loads((synth_dir / "truth.json").read_text())
    T = np.array(truth["T_cam_lidar"])
    from radarcal.camera import Camera

    cam = Camera.from_dict(truth["camera"])
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(4, 12, 12), rng.uniform(-3, 3, 12), rng.uniform(-1, 2, 12)])
    uv, _, _ = cam.project_from(T, p)
    uv += rng.normal(0, 0.5, uv.shape)
    f = tmp_path / "c.csv"
    f.write_text("x,y,z,u,v\n" + "\n".join(",".join(f"{v:.6f}" for v in row) for row in np.column_stack([p, uv])))
    import shutil

    shutil.copy(synth_dir / "bundle.yaml", tmp_path / "b.yaml")
    capsys.readouterr()
    assert main(["lidar-camera", "-b", str(tmp_path / "b.yaml"), "--corners", str(f), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert geometry.pose_error(np.array(out["T_cam_lidar"]), T)[0] < 0.1
    assert out["pnp"]["rms_px"] < 1.0


def test_bad_inputs_exit_2(synth_dir, tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n")
    assert main(["lidar-camera", "-b", str(synth_dir / "bundle.yaml"), "--corners", str(bad)]) == 2
    assert "bad.csv" in capsys.readouterr().err
    assert main(["lidar-camera", "-b", str(synth_dir / "bundle.yaml"), "--image", str(synth_dir / "image.png"), "--refine"]) == 2
    assert main(["lidar-camera", "-b", str(synth_dir / "bundle.yaml"), "--camera", "nope", "--corners", str(bad)]) == 2


def test_not_converged_exits_1_and_stores_nothing(synth_dir, tmp_path, capsys):
    import shutil

    import cv2

    shutil.copy(synth_dir / "bundle.yaml", tmp_path / "b.yaml")
    before = (tmp_path / "b.yaml").read_bytes()
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((1024, 1280), 128, np.uint8))  # no image edges: nothing to align with
    capsys.readouterr()
    rc = main(["lidar-camera", "-b", str(tmp_path / "b.yaml"), "--image", str(blank), "--cloud", str(synth_dir / "cloud.pcd"),
               "--init", str(synth_dir / "init.json"), "--refine", "--search-deg", "0", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and not out["stored"] and not out["refine"]["converged"]
    assert (tmp_path / "b.yaml").read_bytes() == before


@pytest.mark.slow
def test_refine_cli_image_edges_auto(synth_dir, tmp_path, capsys):
    # --image-edges auto refines with LSD and LSD+Canny edges and keeps the pose that aligns better with Canny edges
    import shutil

    shutil.copy(synth_dir / "bundle.yaml", tmp_path / "b.yaml")
    capsys.readouterr()
    rc = main(["lidar-camera", "-b", str(tmp_path / "b.yaml"), "--image", str(synth_dir / "image.png"), "--cloud", str(synth_dir / "cloud.pcd"),
               "--init", str(synth_dir / "init.json"), "--refine", "--image-edges", "auto", "--json"])
    out = json.loads(capsys.readouterr().out)
    choice = out["image_edges_choice"]
    assert choice["chosen"] in ("lsd", "lsd+canny") and choice["canny_alignment_cost_px2"][choice["chosen"]] == min(choice["canny_alignment_cost_px2"].values())
    assert rc == 0 and out["stored"]
    from radarcal.bundle import load_bundle

    T = load_bundle(tmp_path / "b.yaml").T("cam0", "lidar0")
    deg, m = geometry.pose_error(T, np.array(json.loads((synth_dir / "truth.json").read_text())["T_cam_lidar"]))
    assert deg < 0.15 and m < 0.03


def test_refine_method_dense_cli(synth_dir, tmp_path, capsys):
    import shutil

    shutil.copy(synth_dir / "bundle.yaml", tmp_path / "b.yaml")
    capsys.readouterr()
    rc = main(["lidar-camera", "-b", str(tmp_path / "b.yaml"), "--image", str(synth_dir / "image.png"), "--cloud", str(synth_dir / "cloud.pcd"),
               "--init", str(synth_dir / "init.json"), "--refine", "--refine-method", "dense", "--force", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["stored"] and "dense-edge-correlation" in out["method"]
    truth = np.array(json.loads((synth_dir / "truth.json").read_text())["T_cam_lidar"])
    deg, m = geometry.pose_error(np.array(out["T_cam_lidar"]), truth)
    assert deg < 0.3 and m < 0.03, (deg, m)
    q = out["refine_dense"]
    assert q["edge_score_after_px"] < q["edge_score_before_px"] and q["dense_score_after"] > q["dense_score_before"]
    assert main(["lidar-camera", "-b", str(tmp_path / "b.yaml"), "--image", str(synth_dir / "image.png"), "--cloud", str(synth_dir / "cloud.pcd"),
                 "--refine", "--refine-method", "nope"]) == 2


def _scene_bag(synth_dir, path):
    from bag_writer import write_ros1_livox_bag

    from radarcal.io import read_cloud

    c = read_cloud(synth_dir / "cloud.pcd")
    refl = np.clip(np.rint(c.intensity), 0, 255).astype(np.uint8)
    parts = np.array_split(np.arange(len(c)), 5)
    return write_ros1_livox_bag(path, [c.points[i] for i in parts], [1700000000.0 + 0.1 * k for k in range(5)], refl=[refl[i] for i in parts])


def test_bag_cloud_errors_name_the_bag(synth_dir, tmp_path, capsys):
    bag = _scene_bag(synth_dir, tmp_path / "scene.bag")
    capsys.readouterr()
    assert main(["lidar-camera", "-b", str(synth_dir / "bundle.yaml"), "--image", str(synth_dir / "image.png"), "--cloud", str(bag), "--cloud-topic", "/nope", "--refine"]) == 2
    assert f"error: {bag}: no Livox CustomMsg / PointCloud2 topic /nope" in capsys.readouterr().err


@pytest.mark.slow
def test_refine_cli_reads_the_cloud_from_a_bag(synth_dir, tmp_path, capsys):
    """The same scene recorded as a ROS1 bag of 5 Livox CustomMsg clouds (written by rosbags): merged by the cloud
    layer, it calibrates to the same accuracy as the PCD."""
    import shutil

    bag = _scene_bag(synth_dir, tmp_path / "scene.bag")
    shutil.copy(synth_dir / "bundle.yaml", tmp_path / "b.yaml")
    capsys.readouterr()
    rc = main(["lidar-camera", "-b", str(tmp_path / "b.yaml"), "--image", str(synth_dir / "image.png"), "--cloud", str(bag), "--cloud-topic", "/livox/lidar",
               "--init", str(synth_dir / "init.json"), "--refine", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["stored"]
    truth = np.array(json.loads((synth_dir / "truth.json").read_text())["T_cam_lidar"])
    deg, m = geometry.pose_error(np.array(out["T_cam_lidar"]), truth)
    assert deg < 0.15 and m < 0.03, (deg, m)

"""`radarcal lidar-camera --lidar-edges intensity` on a generated single spinning sweep, and its bad inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radarcal import geometry
from radarcal.cli.main import main


@pytest.fixture(scope="module")
def spin_dir(tmp_path_factory):
    pytest.importorskip("open3d")
    out = tmp_path_factory.mktemp("spin")
    # one 0.1 s sweep of a 64-beam LiDAR (1.2 M points/s); initial guess 1 deg off, translation known (--rotation-only)
    assert main(["synth", "lidar-camera", "-o", str(out), "--seed", "3", "--lidar", "spinning", "--duration", "0.1", "--rate", "1.2e6",
                 "--supersample", "1", "--init-deg", "1", "--init-m", "0", "--json"]) == 0
    return out


def _args(d, *extra):
    return ["lidar-camera", "-b", str(d / "bundle.yaml"), "--image", str(d / "image.png"), "--cloud", str(d / "cloud.pcd"), "--init", str(d / "init.json"),
            "--refine", "--rotation-only", "--image-edges", "canny", "--image-edge-min-px", "20", "--search-deg", "3", "--json", *extra]


def test_intensity_edges_rotation_only(spin_dir, capsys):
    capsys.readouterr()
    rc = main(_args(spin_dir, "--lidar-edges", "intensity"))
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["stored"] and out["refine"]["converged"]
    T_true = np.array(json.loads((spin_dir / "truth.json").read_text())["T_cam_lidar"])
    deg, m = geometry.pose_error(np.array(out["T_cam_lidar"]), T_true)
    assert deg < 0.1 and m < 0.005
    assert out["refine"]["lidar_edge_samples"][0] > 100 and out["refine"]["edge_score_after_px"] < out["refine"]["edge_score_before_px"]


def test_intensity_edges_bad_inputs(spin_dir, tmp_path, capsys):
    from radarcal.io import read_cloud, write_pcd

    c = read_cloud(spin_dir / "cloud.pcd")
    write_pcd(tmp_path / "noint.pcd", c.points)  # no intensity field
    args = _args(spin_dir, "--lidar-edges", "intensity")
    args[args.index("--cloud") + 1] = str(tmp_path / "noint.pcd")
    capsys.readouterr()
    assert main(args) == 2
    assert "noint.pcd" in capsys.readouterr().err
    assert main(_args(spin_dir, "--lidar-edges", "reflectivity")) == 2
    assert "--lidar-edges" in capsys.readouterr().err

"""`radarcal run --drift-check-s` on generated replays whose LiDAR is bumped mid-run by a known amount (truth known):
the summary and its warnings (and stderr) say so within a few seconds; the unbumped replay says nothing. Paced at
real time (--speed 1): under heavy load (load average > 10 on 2 cores) a check finishes only every 2-3 s."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from radarcal import geometry
from radarcal.cli.main import main
from radarcal.io import read_cloud
from radarcal.io.clouds import write_pcd
from tests.conftest import shared_dataset

T_BUMP = 2.5


def _replay(tmp_path, family: str, capsys):
    field = "rmuc_schematic"
    if family == "mesh":
        shared_dataset("hitsz_rmuc_field_meshes")
        field = "docs/fields/hitsz_rmuc2024.field.yaml"
    rep = tmp_path / "rep"
    assert main(["synth", "field", str(rep), "--field", field, "--frames", "240", "--seed", "4", "--image-every", "1000", "--json"]) == 0
    capsys.readouterr()
    return rep


def _bump(rep, dst, bump_deg: float, bump_m: float):
    """A copy of the replay whose LiDAR sits at a moved pose from T_BUMP on: the same world points, expressed in the
    moved LiDAR's frame (p' = T_lidar1_field · T_field_lidar0 · p)."""
    shutil.copytree(rep, dst)
    T0 = np.array(json.loads((rep / "truth.json").read_text())["T_field_lidar0"])
    T1 = geometry.perturb_T(T0, bump_deg, bump_m, np.random.default_rng(3))
    M = geometry.invert_T(T1) @ T0
    for line in (dst / "clouds" / "times.csv").read_text().splitlines()[1:]:
        name, t = line.split(",")
        if float(t) >= T_BUMP:
            c = read_cloud(dst / "clouds" / name)
            write_pcd(dst / "clouds" / name, geometry.transform_points(M, np.asarray(c.points, float)), c.intensity)
    return dst, T0, T1


def _run(rep, capsys):
    code = main(["run", "--replay", str(rep), "--drift-check-s", "1", "--speed", "1", "--json"])
    cap = capsys.readouterr()
    assert code == 0
    return json.loads(cap.out), cap.err


@pytest.mark.slow
@pytest.mark.parametrize("family", ["schematic", "mesh"])
def test_run_warns_when_the_lidar_is_bumped(tmp_path, capsys, family):
    rep = _replay(tmp_path, family, capsys)
    s, err = _run(rep, capsys)
    d = s["drift"]
    assert d["checks"] >= 2 and not d["moved"] and not d["warnings"] and not any("moved" in w for w in s["warnings"]), d
    assert d["max"]["cm"] < 1.0 and d["max"]["deg"] < 0.05, d["max"]

    bumped, T0, T1 = _bump(rep, tmp_path / "bumped", 0.3, 0.03)
    s, err = _run(bumped, capsys)
    d = s["drift"]
    assert d["moved"] and d["first_warning_t"] - T_BUMP <= 5.0, d
    assert any("lidar0 is" in w and "moved at t=" in w for w in s["warnings"]), s["warnings"]
    assert "warning: lidar0 is" in err  # said on stderr when it happened
    true_deg, true_m = geometry.pose_error(T1, T0)
    assert abs(d["last"]["cm"] - 100 * true_m) < 0.7 and abs(d["last"]["deg"] - true_deg) < 0.03, (d["last"], true_m, true_deg)


def test_drift_option_checked(tmp_path, capsys):
    assert main(["run", "--replay", "datasets/sample_replay", "--drift-check-s", "-1", "--json"]) == 2
    assert "--drift-check-s" in capsys.readouterr().err

"""`radarcal bundle ...` end to end: exit codes, one-line errors, clean --json stdout."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from radarcal import geometry as g
from radarcal.bundle import load_bundle
from radarcal.cli.main import main

REPO = Path(__file__).resolve().parents[2]
K = [[863.590518437255, 0.116814496662654, 621.666074631063], [0, 863.100180533059, 533.971978652819], [0, 0, 1]]
DIST = [-0.0944205499243979, 0.0946727677776504, -0.00807970960613932, 8.07461209775283e-05, 6.52716646875879e-05]


@pytest.fixture
def files(tmp_path):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"image_size": [1280, 1024], "K": K, "dist": DIST, "model": "pinhole"}))
    T = g.T_from_xyz_rpy_deg(0.05, -0.12, 0.03, -90.1, 0.3, -89.7)
    tf = tmp_path / "T.json"
    tf.write_text(json.dumps({"T_cam0_lidar0": T.tolist()}))
    pose = tmp_path / "pose.txt"
    pose.write_text("14.0 -1.5 2.6 -101.0 0.5 179.0\n")
    return {"cam": cam, "T": tf, "T_value": T, "pose": pose, "bundle": tmp_path / "rig.yaml", "dir": tmp_path}


def _run(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _one_error_line(err: str, path) -> None:
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"error: {path}: "), err


def test_full_workflow(files, capsys):
    b = files["bundle"]
    code, out, err = _run(capsys, "bundle", "import", b, files["cam"], "--camera", "cam0")
    assert code == 0 and f"imported cam0 from {files['cam']} (json)" in out and "fx=863.591" in out
    code, out, err = _run(capsys, "bundle", "set-transform", b, "cam0", "lidar0", files["T"])
    assert code == 0 and out.startswith("set T_cam0_lidar0: xyz=(0.0500, -0.1200, 0.0300) m rpy=(-90.100, 0.300, -89.700) deg")
    code, out, err = _run(capsys, "bundle", "set-transform", b, "field", "cam0", files["pose"])
    assert code == 0
    code, out, err = _run(capsys, "bundle", "validate", b)
    assert code == 0 and out.strip() == f"ok: {b}: 1 camera(s), 2 transform(s)"
    code, out, err = _run(capsys, "bundle", "show", b)
    assert code == 0 and "camera cam0: pinhole 1280x1024" in out and "T_cam0_lidar0: xyz=(0.0500, -0.1200, 0.0300) m" in out
    assert "T_field_cam0: xyz=(14.0000, -1.5000, 2.6000) m  rpy=(-101.000, 0.500, 179.000) deg" in out
    bundle = load_bundle(b)
    assert np.array_equal(bundle.camera("cam0").K, K) and np.array_equal(bundle.camera("cam0").dist, DIST)
    assert np.array_equal(bundle.T("cam0", "lidar0"), files["T_value"])
    np.testing.assert_allclose(bundle.T("field", "lidar0"), g.T_from_xyz_rpy_deg(14.0, -1.5, 2.6, -101.0, 0.5, 179.0) @ files["T_value"], atol=1e-12)
    prov = bundle.transforms["T_cam0_lidar0"].provenance
    assert prov.command == f"radarcal bundle set-transform {b} cam0 lidar0 {files['T']}"
    assert len(prov.inputs_sha256) == 64 and prov.time.startswith("20")
    assert bundle.cameras["cam0"].provenance.command == f"radarcal bundle import {b} {files['cam']} --camera cam0"
    assert bundle.transforms["T_cam0_lidar0"].method == "manual (set-transform)"


def test_show_json_is_clean(files, capsys):
    b = files["bundle"]
    main(["bundle", "import", str(b), str(files["cam"]), "--camera", "cam0"])
    main(["bundle", "set-transform", str(b), "cam0", "lidar0", str(files["T"])])
    capsys.readouterr()
    code, out, err = _run(capsys, "bundle", "show", b, "--json")
    assert code == 0
    d = json.loads(out)  # the whole of stdout is one JSON document
    assert d["cameras"]["cam0"]["K"] == K and d["cameras"]["cam0"]["dist"] == DIST
    assert d["transforms"]["T_cam0_lidar0"]["T"] == files["T_value"].tolist()
    np.testing.assert_allclose(d["transforms"]["T_cam0_lidar0"]["rpy_deg"], [-90.1, 0.3, -89.7], atol=1e-9)
    assert d["runtime"]["hero_range_offset_m"] == 0.0 and d["path"] == str(b)
    code, out, err = _run(capsys, "bundle", "import", b, files["cam"], "--camera", "cam1", "--json")
    d = json.loads(out)
    assert code == 0 and d["camera"] == "cam1" and d["format"] == "json" and d["K"] == K
    code, out, err = _run(capsys, "bundle", "validate", b, "--json")
    assert code == 0 and json.loads(out) == {"ok": True, "path": str(b), "cameras": ["cam0", "cam1"], "transforms": ["T_cam0_lidar0"]}
    code, out, err = _run(capsys, "bundle", "set-transform", b, "field", "cam0", files["pose"], "--json")
    d = json.loads(out)
    assert code == 0 and d["name"] == "T_field_cam0" and d["xyz_m"] == [14.0, -1.5, 2.6]
    np.testing.assert_allclose(d["rpy_deg"], [-101.0, 0.5, 179.0], atol=1e-9)
    np.testing.assert_allclose(d["T"], g.T_from_xyz_rpy_deg(14.0, -1.5, 2.6, -101.0, 0.5, 179.0), atol=1e-15)
    code, out, err = _run(capsys, "bundle", "export", b, "--camera", "cam0", "--format", "ros", "--json")
    d = json.loads(out)
    assert code == 0 and d["format"] == "ros" and d["output"] is None
    assert yaml.safe_load(d["text"])["camera_matrix"]["data"] == np.ravel(K).tolist()
    target = files["dir"] / "cam0.yaml"
    code, out, err = _run(capsys, "bundle", "export", b, "--camera", "cam0", "--format", "opencv", "-o", target, "--json")
    assert code == 0 and json.loads(out)["output"] == str(target) and target.read_text() == json.loads(out)["text"]


@pytest.mark.parametrize("fmt", ["ros", "opencv", "kalibr", "json"])
def test_export_to_stdout_and_file_round_trips(files, capsys, fmt):
    b = files["bundle"]
    cam4 = files["dir"] / "cam4.json"
    cam4.write_text(json.dumps({"image_size": [1280, 1024], "K": [[900.5, 0, 640.25], [0, 899.75, 512.125], [0, 0, 1]], "dist": [-0.31, 0.12, 1e-3, -2e-4], "model": "pinhole"}))
    main(["bundle", "import", str(b), str(cam4), "--camera", "cam0"])
    capsys.readouterr()
    code, out, err = _run(capsys, "bundle", "export", b, "--camera", "cam0", "--format", fmt)
    assert code == 0 and err == ""
    outfile = files["dir"] / f"exported.{fmt}.yaml"
    code, out2, err2 = _run(capsys, "bundle", "export", b, "--camera", "cam0", "--format", fmt, "-o", outfile)
    assert code == 0 and out2 == "" and err2.strip() == f"wrote {outfile} ({fmt})"
    assert outfile.read_text() == out
    b2 = files["dir"] / "other.yaml"
    assert main(["bundle", "import", str(b2), str(outfile), "--camera", "camX"]) == 0
    src, dst = load_bundle(b).camera("cam0"), load_bundle(b2).camera("camX")
    assert np.array_equal(src.K, dst.K) and np.array_equal(src.dist, dst.dist) and src.image_size == dst.image_size


BAD = [
    # (args builder, which file the error must name, message fragment)
    (lambda f: ["bundle", "show", f["dir"] / "nope.yaml"], lambda f: f["dir"] / "nope.yaml", "bundle not found"),
    (lambda f: ["bundle", "validate", f["bad_bundle"]], lambda f: f["bad_bundle"], "cameras.cam0.K: expected 3x3, got 3x2"),
    (lambda f: ["bundle", "show", f["bad_bundle"], "--json"], lambda f: f["bad_bundle"], "cameras.cam0.K: expected 3x3, got 3x2"),
    (lambda f: ["bundle", "import", f["bundle"], f["dir"] / "missing.yaml", "--camera", "cam0"], lambda f: f["dir"] / "missing.yaml", "file not found"),
    (lambda f: ["bundle", "import", f["bundle"], f["garbage"], "--camera", "cam0", "--json"], lambda f: f["garbage"], "unrecognised camera file"),
    (lambda f: ["bundle", "import", f["bad_bundle"], f["cam"], "--camera", "cam0"], lambda f: f["bad_bundle"], "cameras.cam0.K"),
    (lambda f: ["bundle", "import", f["bundle"], f["cam"], "--camera", "cam0", "--image-size", "big"], lambda f: "--image-size", "expected WIDTHxHEIGHT"),
    (lambda f: ["bundle", "export", f["good"], "--camera", "cam9"], lambda f: f["good"], "no camera 'cam9' in the bundle (cameras: cam0)"),
    (lambda f: ["bundle", "export", f["good"], "--camera", "cam0", "--format", "matlab"], lambda f: "--format", "unknown format 'matlab'"),
    (lambda f: ["bundle", "export", f["good"], "--camera", "cam0", "-o", f["dir"] / "no" / "such" / "dir.yaml"], lambda f: f["dir"] / "no" / "such" / "dir.yaml", "cannot write"),
    (lambda f: ["bundle", "set-transform", f["bundle"], "cam0", "lidar0", f["garbage"]], lambda f: f["garbage"], "expected 16 numbers"),
    (lambda f: ["bundle", "set-transform", f["bundle"], "cam0", "lidar0", f["non_rigid"]], lambda f: f["non_rigid"], "rotation part is not orthonormal"),
    (lambda f: ["bundle", "set-transform", f["bundle"], "cam0", "lidar0", f["dir"] / "nope.json"], lambda f: f["dir"] / "nope.json", "file not found"),
    (lambda f: ["bundle", "set-transform", f["bundle"], "cam0", "cam0", f["T"], "--json"], lambda f: "TARGET/SOURCE", "two different frames"),
    (lambda f: ["bundle", "validate", f["garbage"], "--json"], lambda f: f["garbage"], "schema_version: expected an integer"),
]


@pytest.fixture
def bad_files(files):
    f = dict(files)
    main(["bundle", "import", str(files["dir"] / "good.yaml"), str(files["cam"]), "--camera", "cam0"])
    f["good"] = files["dir"] / "good.yaml"
    d = yaml.safe_load(f["good"].read_text())
    d["cameras"]["cam0"]["K"] = [[800, 0], [0, 800], [0, 0]]
    f["bad_bundle"] = files["dir"] / "bad.yaml"
    f["bad_bundle"].write_text(yaml.safe_dump(d))
    f["garbage"] = files["dir"] / "garbage.yaml"
    f["garbage"].write_text("hello: [1, 2]\n")
    f["non_rigid"] = files["dir"] / "scaled.txt"
    f["non_rigid"].write_text("2 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n")
    return f


@pytest.mark.parametrize("i", range(len(BAD)))
def test_bad_input_exit_2_one_line(bad_files, capsys, i):
    args, culprit, fragment = BAD[i]
    capsys.readouterr()
    before = {p: p.read_bytes() for p in bad_files["dir"].iterdir() if p.is_file()}
    code, out, err = _run(capsys, *args(bad_files))
    assert code == 2, err
    _one_error_line(err, culprit(bad_files))
    assert fragment in err
    assert out == ""  # nothing on stdout, also with --json
    # no file was created or changed by a failed command
    after = {p: p.read_bytes() for p in bad_files["dir"].iterdir() if p.is_file()}
    assert after == before


def test_debug_shows_the_traceback(files, capsys):
    with pytest.raises(Exception) as e:
        main(["--debug", "bundle", "show", str(files["dir"] / "nope.yaml")])
    assert "bundle not found" in str(e.value)


def test_help_and_usage_errors(capsys):
    assert main(["--help"]) == 0
    assert "bundle" in capsys.readouterr().out
    assert main(["bundle", "--help"]) == 0
    out = capsys.readouterr().out
    for sub in ("show", "validate", "import", "export", "set-transform"):
        assert sub in out
    code = main(["bundle", "import", "x.yaml"])  # missing FILE and --camera
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err


def _subprocess(*args):
    env = dict(os.environ, PYTHONPATH=str(REPO), RADARCAL_DEBUG="0")
    return subprocess.run([sys.executable, "-m", "radarcal", *map(str, args)], capture_output=True, text=True, env=env, timeout=120, cwd=REPO)


def test_real_subprocess(files):
    b = files["bundle"]
    p = _subprocess("bundle", "import", b, files["cam"], "--camera", "cam0", "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["K"] == K
    p = _subprocess("bundle", "show", b, "--json")
    assert p.returncode == 0 and json.loads(p.stdout)["cameras"]["cam0"]["dist"] == DIST
    p = _subprocess("bundle", "export", b, "--camera", "cam0", "--format", "ros")
    assert p.returncode == 0 and yaml.safe_load(p.stdout)["camera_matrix"]["data"] == np.ravel(K).tolist()
    p = _subprocess("bundle", "validate", files["dir"] / "missing.yaml")
    assert p.returncode == 2 and p.stdout == ""
    _one_error_line(p.stderr, files["dir"] / "missing.yaml")
    assert "bundle not found" in p.stderr

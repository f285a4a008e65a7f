"""``lidar-camera --ui``: the nudge parameterisation, and in a real headless Chromium the keys undoing a known
mis-mounting of the cloud over a generated scene (the taken pose becomes the command's initial guess)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from radarcal import geometry
from radarcal.cli.main import main
from radarcal.extrinsics.nudge_ui import apply_nudge

REPO = Path(__file__).resolve().parents[2]


def test_nudge_moves_the_cloud_in_the_camera_frame():
    rng = np.random.default_rng(1)
    T = geometry.make_T(geometry.rpy_deg_to_R(-90, 0, -90), [0.1, -0.05, 0.02])
    p = rng.normal(0, 5, (20, 3))
    p_cam = geometry.transform_points(T, p)
    # translations: every point moves by the same camera-frame vector
    np.testing.assert_allclose(geometry.transform_points(apply_nudge(T, [0.1, -0.02, 0.5, 0, 0, 0]), p) - p_cam, np.tile([0.1, -0.02, 0.5], (20, 1)), atol=1e-12)
    # pan: the whole cloud turns about the camera's y axis (the camera centre fixed)
    Ry = geometry.rpy_deg_to_R(0, 2.0, 0)
    np.testing.assert_allclose(geometry.transform_points(apply_nudge(T, [0, 0, 0, 0, 2.0, 0]), p), p_cam @ Ry.T, atol=1e-12)
    # a single-axis nudge and its opposite cancel exactly
    np.testing.assert_allclose(apply_nudge(apply_nudge(T, [0, 0, 0, 0.5, 0, 0]), [0, 0, 0, -0.5, 0, 0]), T, atol=1e-12)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("lc_ui")
    assert main(["synth", "lidar-camera", "-o", str(out), "--seed", "4", "--duration", "3", "--boards", "0", "--json"]) == 0
    return out


@pytest.mark.slow  # the generated scene takes ~45 s on the loaded 2-core machine
def test_keys_in_chromium_undo_a_known_offset(scene, tmp_path, browser, screenshot, capsys):
    from selenium.webdriver.common.action_chains import ActionChains

    truth = json.loads((scene / "truth.json").read_text())
    T_true = np.array(truth["T_cam_lidar"])
    T_off = apply_nudge(T_true, [0, 0, 0, 0, 2.0, 0])  # mounted 2 deg panned: one coarse pan step
    init = tmp_path / "init.json"
    init.write_text(json.dumps(T_off.tolist()))
    # correspondences so the command has something to solve after the nudge (its result does not depend on it)
    from radarcal.camera import Camera

    cam = Camera.from_dict(truth["camera"])
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(4, 12, 12), rng.uniform(-3, 3, 12), rng.uniform(-1, 2, 12)])
    uv, _, _ = cam.project_from(T_true, p)
    corners = tmp_path / "c.csv"
    corners.write_text("x,y,z,u,v\n" + "\n".join(",".join(f"{v:.6f}" for v in row) for row in np.column_stack([p, uv])))
    shutil.copy(scene / "bundle.yaml", tmp_path / "b.yaml")
    cmd = [sys.executable, "-m", "radarcal", "lidar-camera", "-b", str(tmp_path / "b.yaml"), "--image", str(scene / "image.png"), "--cloud", str(scene / "cloud.pcd"),
           "--init", str(init), "--corners", str(corners), "--ui", "127.0.0.1:0", "--json"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "MPLBACKEND": "Agg"})
    try:
        line, t_end = "", time.time() + 60
        while time.time() < t_end and not (m := re.search(r"lidar-camera: (http://\S+)#token=(\S+)", line)):
            line = proc.stderr.readline()
            assert line or proc.poll() is None, proc.stderr.read()
        browser.get(m.group(1) + "#token=" + m.group(2))
        t = time.time() + 10
        while not browser.execute_script("return window.__nudge && window.__nudge.ready;") and time.time() < t:
            time.sleep(0.05)
        before = screenshot(browser, "lidar_camera_nudge_before")
        ActionChains(browser).send_keys("5").send_keys("c").send_keys("\ue012").perform()  # pan, coarse, ArrowLeft: -2 deg
        t = time.time() + 10
        while browser.execute_script("return window.__nudge.updates;") < 1 and time.time() < t:
            time.sleep(0.05)
        time.sleep(0.5)
        after = screenshot(browser, "lidar_camera_nudge_after")
        state = browser.execute_script("return [window.__nudge.nudge, window.__nudge.frame];")
        browser.find_element("id", "take").click()
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert state[0] == [0, 0, 0, 0, -2.0, 0] and state[1] >= 1
    s = json.loads(out)
    assert s["init"].startswith("nudged in the browser from")
    from radarcal.bundle import load_bundle, load_session

    arrays, _ = load_session(load_bundle(tmp_path / "b.yaml"), "lidar_camera/cam0_lidar0")
    deg, m_ = geometry.pose_error(arrays["T_init"], T_true)  # the page's nudge undid the mis-mounting exactly
    assert deg < 1e-9 and m_ < 1e-9
    import cv2

    a, b = cv2.imread(str(before)), cv2.imread(str(after))
    assert a.std() > 20 and np.abs(a.astype(int) - b.astype(int)).mean() > 0.5  # the cloud moved on the page

"""Several cameras in the runtime (issue #19): time pairing, detection per tick, fusion of one robot's fixes."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.errors import InputError
from radarcal.runtime.detector import Detection
from radarcal.geometry import invert_T
from radarcal.runtime.localise import Localiser
from radarcal.runtime.lidar_first import box_fix_order, fuse_fixes, misread_holder, on_other_robot
from radarcal.runtime.multicam import TickDetector, group_by_time, missing_text, parse_videos
import radarcal.runtime.pipeline as P
from radarcal.runtime.pipeline import boxes_in_front, foot_beyond, fuse_by_label, no_ground_ray
from radarcal.runtime.sources import CameraFrame
from radarcal.runtime.tracks import Tracker3D


def _frames(times, prefix=""):
    return [CameraFrame(float(t), f"{prefix}{i:03d}", lambda: None, i) for i, t in enumerate(times)]


def test_group_by_time_pairs_and_reports_a_missing_camera():
    a = _frames(np.arange(30) / 30)
    b = _frames([t for t in np.arange(30) / 30 + 0.011 if not 0.3 < t < 0.9])  # cam1 unplugged 0.3 .. 0.9 s
    ticks = list(group_by_time({"cam0": a, "cam1": b}, window_s=0.017, missing_after_s=0.2))
    assert len(ticks) == 30  # every cam0 frame opens a tick; cam1 frames join the tick 11 ms before them
    for tk in ticks:
        f0 = tk.frames["cam0"]
        if "cam1" in tk.frames:
            assert 0 < tk.frames["cam1"].t - f0.t < 0.017 and tk.t == tk.frames["cam1"].t
        assert tk.name == f"cam0/{f0.name}"
    gap = [tk for tk in ticks if "cam1" not in tk.frames]
    assert len(gap) == 18 and all(tk.frames["cam0"].t > 0.29 for tk in gap)
    late = [tk for tk in gap if tk.t - 0.3 > 0.2 + 1 / 30]
    assert late and all(tk.missing == ["cam1"] for tk in late) and all(not tk.missing for tk in ticks if "cam1" in tk.frames)
    assert "cam1 MISSING" in missing_text(["cam1"]) and missing_text([]) == ""
    # one camera far behind the other still pairs by time, never by arrival order
    ticks = list(group_by_time({"cam0": _frames([0.0, 0.1, 0.2]), "cam1": _frames([0.105, 0.31])}, window_s=0.017))
    assert [sorted(tk.frames) for tk in ticks] == [["cam0"], ["cam0", "cam1"], ["cam0"], ["cam1"]]


def test_tick_detector_one_batched_call_per_tick():
    calls = []

    class Rec:
        last_timings_ms = {"robot": 1.0}

        def __call__(self, images, cameras=None):
            calls.append((len(images), cameras))
            return [[Detection(np.array([0.0, 0.0, 10.0, 10.0]), f"blue_{int(im[0, 0])}", 0.9)] for im in images]

    f0 = CameraFrame(1.0, "a", lambda: np.full((4, 4), 1.0), 0)
    f1 = CameraFrame(0.99, "b", lambda: np.full((4, 4), 3.0), 0)
    ticks = list(group_by_time({"cam0": [f0], "cam1": [f1]}))
    assert len(ticks) == 1
    vd = TickDetector(recogniser=Rec())(ticks[0])
    assert calls == [(2, ["cam0", "cam1"])]  # one call, each image with its camera (the far-robot windows)
    assert [(c, t, n, d[0].label) for c, t, n, d in vd.views] == [("cam1", 0.99, "b", "blue_3"), ("cam0", 1.0, "a", "blue_1")]


def test_parse_videos():
    assert parse_videos(["/dev/video0"]) is None and parse_videos(["rtsp://x/y"]) is None
    assert parse_videos(["cam0=0", "cam1=rtsp://h/s"]) == {"cam0": "0", "cam1": "rtsp://h/s"}
    for bad in (["cam0=0", "x"], ["cam0=0", "cam0=1"]):
        with pytest.raises(InputError):
            parse_videos(bad)


def _fix(k, j, xy, sigma, label, source="ground", score=0.9):
    return {"k": k, "j": j, "p": np.array([*xy, 0.0]), "sigma": sigma, "source": source, "label": label, "score": score, "t": 1.0, "h": 40.0}


def test_fuse_fixes_one_robot_from_two_cameras():
    wide, tele = _fix(0, 0, (20.0, 5.0), 0.6, "blue_3"), _fix(1, 0, (20.3, 5.1), 0.2, "blue_3")
    other = _fix(1, 1, (22.0, 5.0), 0.2, "blue_4")  # another robot 2 m away: stays apart
    out = fuse_fixes([wide, tele, other])
    assert len(out) == 2
    f = next(o for o in out if len(o["votes"]) == 2)
    w = np.array([1 / 0.6**2, 1 / 0.2**2])
    assert np.allclose(f["p"][:2], (w[0] * np.array([20.0, 5.0]) + w[1] * np.array([20.3, 5.1])) / w.sum())
    assert f["sigma"] == pytest.approx(1 / np.sqrt(w.sum())) and f["label"] == "blue_3"
    # a misread number of the same robot (same colour, 0.1 m apart) joins; the tele's label wins by weight
    out = fuse_fixes([_fix(0, 0, (20.0, 5.0), 0.6, "blue_4"), _fix(1, 0, (20.1, 5.0), 0.2, "blue_3")])
    assert len(out) == 1 and out[0]["label"] == "blue_3" and sorted(v[0] for v in out[0]["votes"]) == ["blue_3", "blue_4"]
    # two boxes of one camera are two robots, even on top of each other; another colour never joins
    assert len(fuse_fixes([_fix(0, 0, (20.0, 5.0), 0.2, "blue_3"), _fix(0, 1, (20.1, 5.0), 0.2, "blue_3")])) == 2
    assert len(fuse_fixes([_fix(0, 0, (20.0, 5.0), 0.2, "blue_3"), _fix(1, 0, (20.1, 5.0), 0.2, "red_3")])) == 2


def test_fuse_by_label_weights_and_gates():
    m = [("blue_1", np.array([10.0, 5.0]), 0.5, "ground", 0.8, np.nan), ("blue_1", np.array([10.4, 5.0]), 0.1, "depth", 0.7, 12.0),
         ("blue_1", np.array([18.0, 5.0]), 0.3, "ground", 0.9, np.nan), ("red_2", np.array([3.0, 3.0]), 0.2, "depth", 0.6, 4.0)]  # fmt: skip
    out = {o[0]: o for o in fuse_by_label(m)}
    xy = (np.array([10.0, 5.0]) / 0.25 + np.array([10.4, 5.0]) / 0.01) / (1 / 0.25 + 1 / 0.01)
    assert np.allclose(out["blue_1"][1], xy) and out["blue_1"][3] == "depth" and out["blue_1"][5] == 12.0  # the one at 18 m is dropped
    assert np.allclose(out["red_2"][1], [3.0, 3.0])


def _coasting(tk, xy, label, t_lidar=0.0):
    tr = tk._new(np.array(xy, float), 0.05, 1.0, 0.0, "lidar")
    tr.label, tr.t_lidar, tr.state = label, t_lidar, "confirmed"
    return tr


def test_a_misread_number_moves_the_robot_s_track_not_a_new_one():
    """A_2 of the benchmark: the LiDAR lost red_3 on a highland edge, the tele reads its number as red_2 (no track
    holds red_2): the fix goes to the red_3 track 0.5 m away, never to one of another colour or out of its gate."""
    tk = Tracker3D()
    red3, blue2 = _coasting(tk, (13.44, 4.73), "red_3"), _coasting(tk, (13.5, 5.6), "blue_2")
    assert misread_holder(tk, None, "red_2", np.array([13.39, 5.24]), 0.077, 1.03, set()) is red3
    assert misread_holder(tk, None, "red_2", np.array([16.4, 4.7]), 0.077, 1.03, set()) is None  # 3 m away: another robot
    assert misread_holder(tk, None, "red_2", np.array([13.39, 5.24]), 0.077, 1.03, {red3.id}) is None  # red_3 has its fix
    red3.t_lidar = 1.0  # seen by the LiDAR now: its boxes are matched by projection, a box-only fix is another robot
    assert misread_holder(tk, None, "red_2", np.array([13.39, 5.24]), 0.077, 1.03, set()) is None
    assert misread_holder(tk, None, "blue_4", np.array([13.5, 5.5]), 0.077, 1.03, set()) is blue2
    # the label's own track within its gate always wins
    red2 = _coasting(tk, (13.2, 5.2), "red_2")
    red3.t_lidar = 0.0
    assert misread_holder(tk, red2, "red_2", np.array([13.39, 5.24]), 0.077, 1.03, set()) is red2


def test_two_fixes_of_one_label_the_one_at_its_track_first():
    """A_2: blue_7 boxed at its track (12.9, 5.2) and blue_4 misread as blue_7 4 m away: the near fix goes first
    (updates blue_7's track); the far one then finds blue_7 taken and cannot move blue_7's track there."""
    tk = Tracker3D()
    b7 = _coasting(tk, (12.9, 5.2), "blue_7")
    far, near = _fix(1, 2, (16.7, 6.9), 0.07, "blue_7"), _fix(0, 2, (12.95, 5.25), 0.07, "blue_7")
    stray = _fix(0, 1, (3.0, 3.0), 0.07, "red_1")
    out = box_fix_order([far, stray, near], {"blue_7": b7})
    assert out[0] is near and out[1] is far and out[2] is stray


def test_a_box_fix_on_another_robot_the_lidar_sees_moves_no_track():
    """A 5 of the benchmark: blue_2, hidden behind red_1, boxed by the tele with red_1's depth: the fix lies on red_1's
    LiDAR track while blue_2's own LiDAR-measured track is 4.4 m away, so it must not move that track (two such fixes
    had moved it 4.4 m there)."""
    tk = Tracker3D()
    blue2, red1 = _coasting(tk, (20.05, 3.75), "blue_2"), _coasting(tk, (15.8, 5.95), "red_1", t_lidar=1.0)
    blue2.n_lidar = 20  # tracked by the LiDAR before it went behind red_1
    fix, s = np.array([15.69, 5.37]), 0.1  # 0.59 m from red_1's track, 4.4 m from blue_2's (outside its gate)
    assert on_other_robot(tk, blue2, "blue_2", fix, s, 1.0, 0.6 + 2 * s, False)
    assert not on_other_robot(tk, blue2, "blue_2", fix, s, 1.0, 0.5, False)  # outside the radius: a robot beside red_1
    assert not on_other_robot(tk, blue2, "red_1", fix, s, 1.0, 0.8, False)  # red_1's own fix (handled by its track)
    red1.t_lidar = 0.5  # the LiDAR lost red_1 too: nothing says the fix is not blue_2
    assert not on_other_robot(tk, blue2, "blue_2", fix, s, 1.0, 0.8, True)
    red1.t_lidar = 1.0
    # blue_2's own LiDAR track gates the fix: two robots side by side (one LiDAR cluster), the fix is blue_2's
    near_own = red1.x[:2] + np.array([-0.35, 0.0])
    blue2.x[:2] = near_own + np.array([0.0, 0.45])
    assert not on_other_robot(tk, blue2, "blue_2", near_own, s, 1.0, 0.8, True)
    unnamed = _coasting(tk, (10.0, 10.0), None, t_lidar=1.0)  # an unnamed LiDAR track: the box names it (not this rule)
    assert not on_other_robot(tk, None, "blue_2", unnamed.x[:2] + 0.1, s, 1.0, 0.8, True)


def test_a_box_fix_beside_another_robot_goes_on_unless_its_box_stands_behind(station):
    """No LiDAR track of the label says where its robot is: the box's own bottom edge does (`foot_beyond`). `synth
    field` seed 12: red_3 0.4 m behind blue_7 (LiDAR-seen), its foot in view, its box depths blue_7's points (0.3 m
    short of red_3): the fix is red_3 (dropping such fixes lost red_3 for 0.6 s). A 5, wide camera alone: blue_4 at
    25 m, no blue_4 track, its box's depth blue_7's at 15.6 m: its ground ray lands metres beyond — dropped; as is a
    box whose foot a robot in front hides (its bottom edge is that robot's outline)."""
    cam, T_field_cam = station["camera"], station["T_field_cam"]
    T_cam_field = invert_T(T_field_cam)

    def box_at(x, y, r=0.25, h=0.45):  # a robot's image box: its top corners and its nearest foot point
        uv, _, _ = cam.project_from(T_cam_field, np.array([[x - r, y - r, h], [x - r, y + r, h], [x - r, y, 0.0], [x + r, y, h]]))
        return np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[2, 1]])

    blue7 = np.array([18.0, 7.5, 0.0])
    boxes = np.array([box_at(18.3, 7.8), box_at(25.0, 8.5), box_at(18.0, 7.5), box_at(16.5, 6.0), box_at(18.5, 5.85)])
    p = np.tile(blue7, (5, 1))  # every box's depth fix: blue_7's points (its centre)
    beyond = foot_beyond(Localiser(cam, T_field_cam), boxes, boxes, p, 0.55)
    assert abs(beyond[0] - 0.3) < 0.1 and abs(beyond[1] - 7.0) < 0.3 and abs(beyond[2]) < 0.05 and beyond[3] < -1.0, beyond
    assert beyond[4] == np.inf  # its bottom centre inside the box of the robot in front (16.5 m): not its foot
    tk = Tracker3D()
    _coasting(tk, blue7[:2], "blue_7", t_lidar=1.0)
    fix, s = blue7[:2], 0.07
    behind = beyond > 0.6 + 2 * s
    assert behind.tolist() == [False, True, False, False, True]
    assert not on_other_robot(tk, None, "red_3", fix, s, 1.0, 0.6 + 2 * s, bool(behind[0]))  # a robot beside blue_7
    assert on_other_robot(tk, None, "blue_4", fix, s, 1.0, 0.6 + 2 * s, bool(behind[1]))  # blue_7's depth
    box_born = _coasting(tk, fix + [0.5, 0.0], "red_3")  # made of such fixes (n_lidar 0): its gate says nothing
    assert not on_other_robot(tk, box_born, "red_3", fix, s, 1.0, 0.6 + 2 * s, False)
    assert on_other_robot(tk, box_born, "red_3", fix, s, 1.0, 0.6 + 2 * s, True)  # A 4: blue_3 behind blue_2


def test_no_ground_ray_from_a_foot_hidden_by_a_robot_in_front():
    """A 5: the tele's box of blue_2 [996, 417, 1103, 505] behind blue_1 [949, 428, 1079, 544]: its bottom edge is
    blue_1's outline, a ground ray from it landed 4.4 m short (on red_1). A box beside it, or in front, keeps it."""
    boxes = np.array([[996, 417, 1103, 505], [949, 428, 1079, 544], [849, 403, 989, 513], [1200, 400, 1260, 480]], float)
    front = boxes_in_front(boxes, boxes)
    assert front.tolist() == [[False, True, False, False], [False] * 4, [False, True, False, False], [False] * 4]  # red_1 ends left of blue_2
    assert no_ground_ray(boxes, boxes, 0.55).tolist() == [True, False, False, False]
    # red_1's box overlaps blue_1's too but its bottom centre (919 px) is left of it: the foot is visible
    assert no_ground_ray(np.array([[800, 300, 860, 330]], float), boxes, 0.55).tolist() == [True]  # flat: a hidden robot's top


def _near_and_far_robot(near_from_z: float = 0.0):
    """The sample replay's camera, a 1.2 m robot 11 m out on its axis (no returns and no pixels below
    ``near_from_z``: a terrain edge hides its foot) and a 0.45 m one 12 m out behind it: (pipeline with that
    cloud, boxes [near, far], their camera-frame depths)."""
    from pathlib import Path

    from runtime_scene import robot_cloud

    from radarcal.bundle import load_bundle
    from radarcal.geometry import invert_T, transform_points
    from radarcal.runtime.loop import Pipeline, RunConfig

    sample = Path(__file__).resolve().parents[2] / "datasets" / "sample_replay"
    if not (sample / "calib.yaml").is_file():
        pytest.skip("datasets/sample_replay missing (python datasets/make_sample.py)")
    b = load_bundle(sample / "calib.yaml")
    pipe = Pipeline(b, "cam0", "lidar0", RunConfig.from_bundle(b, localise="box"))
    T_field_cam = pipe.T_field_cam
    eye = T_field_cam[:2, 3]
    ahead = T_field_cam[:2, 2] / np.linalg.norm(T_field_cam[:2, 2])  # the optical axis on the field
    c_near, c_far = eye + 11.0 * ahead, eye + 12.0 * ahead + 0.1 * np.array([-ahead[1], ahead[0]])
    assert np.allclose(b.field().surface_z(np.array([c_near, c_far])), 0.0)
    near = robot_cloud(c_near, height=1.2, viewer_xy=eye)
    pts = np.vstack([near[near[:, 2] >= near_from_z], robot_cloud(c_far, viewer_xy=eye, rng=np.random.default_rng(1))])
    T_lidar_field = invert_T(T_field_cam @ b.T("cam0", "lidar0"))
    pipe.add_cloud(0.0, transform_points(T_lidar_field, pts))
    T_cam_field = invert_T(T_field_cam)

    def box(c, z0, h):
        ang = np.linspace(0, 2 * np.pi, 32)
        p = np.vstack([np.column_stack([c[0] + 0.25 * np.cos(ang), c[1] + 0.25 * np.sin(ang), np.full(32, z)]) for z in (z0, h)])
        uv, _ = pipe.camera.project(transform_points(T_cam_field, p))
        return np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])

    boxes = np.array([box(c_near, near_from_z, 1.2), box(c_far, 0.0, 0.45)])
    z_near, z_far = transform_points(T_cam_field, np.array([[*(c - 0.2 * ahead), 0.3] for c in (c_near, c_far)]))[:, 2]
    return pipe, boxes, (z_near, z_far)


def test_box_depth_excludes_a_nearer_robot_whose_box_is_not_located():
    """B11 of the benchmark: a robot half hidden behind a nearer one whose box a LiDAR track explains (so only the
    far box is located) took the near robot's depth; every box of the frame must count as an occluder."""
    pipe, boxes, (z_near, z_far) = _near_and_far_robot()
    assert boxes[0, 3] > boxes[1, 3] and boxes[0, 1] < boxes[1, 3]  # the near robot hides the far one's lower part
    alone, _ = pipe._box_depths(boxes[1:], 0.0)  # the near box not given: its robot's pixels win
    with_frame, _ = pipe._box_depths(boxes[1:], 0.0, frame_boxes=boxes)
    assert abs(alone[0] - z_near) < 0.3
    assert abs(with_frame[0] - z_far) < 0.3


def test_box_depth_orders_overlapping_boxes_by_their_own_lidar_depth():
    """Families A / B beyond 15 m: most box depths more than 0.4 m short were a robot in front whose box bottom
    is not lower (a terrain edge hides its foot): the bottom-edge order called it the one behind, so its pixels
    stayed in the far box. The depths of the boxes' own pixels say which is in front; the near box keeps its own."""
    pipe, boxes, (z_near, z_far) = _near_and_far_robot(near_from_z=0.35)
    assert boxes[0, 3] < boxes[1, 3] - 2 and boxes[0, 1] < boxes[1, 1] < boxes[0, 3]  # near box: bottom higher, overlapping
    assert not boxes_in_front(boxes[1:], boxes).any()  # by the bottom edges the near robot is behind
    depth, _ = pipe._box_depths(boxes, 0.0)
    assert abs(depth[1] - z_far) < 0.3 and abs(depth[0] - z_near) < 0.3


def test_box_depths_from_the_depth_orders_query_equal_a_second_query_with_the_boxes_in_front():
    """The depth order's query also answers the boxes with nothing in front (read whole) and those whose every
    overlapping box is in front (their own pixels): the result must be what a second query excluding each box's
    boxes in front gives — on random crowds of overlapping boxes, located boxes the frame's boxes, a subset of them,
    or boxes not among them."""
    from runtime_scene import robot_cloud

    from radarcal.geometry import invert_T, transform_points

    pipe, _, _ = _near_and_far_robot()
    rng = np.random.default_rng(7)
    T_field_cam = pipe.T_field_cam
    T_lidar_field = invert_T(T_field_cam @ pipe.views["cam0"].queue.T_cam_lidar)
    eye, ahead = T_field_cam[:2, 3], T_field_cam[:2, 2] / np.linalg.norm(T_field_cam[:2, 2])
    side = np.array([-ahead[1], ahead[0]])
    at = eye + rng.uniform(6, 16, (8, 1)) * ahead + rng.uniform(-2, 2, (8, 1)) * side
    pts = np.vstack([robot_cloud(c, height=float(rng.uniform(0.4, 1.2)), viewer_xy=eye, rng=rng) for c in at])
    pipe.add_cloud(0.05, transform_points(T_lidar_field, pts))
    q, T_cam_field = pipe.views["cam0"].queue, invert_T(T_field_cam)
    uv, _ = pipe.camera.project(transform_points(T_cam_field, np.column_stack([at, np.full(8, 0.3)])))
    shortcuts = checked = found = 0
    for trial in range(60):
        n = int(rng.integers(2, 9))
        c = uv[rng.integers(0, 8, n)] + rng.normal(0, 25, (n, 2))
        half = rng.uniform([10, 15], [45, 70], (n, 2))
        fb = np.column_stack([c - half, c + half])
        b = [fb, fb[rng.permutation(n)[: max(1, n // 2)]], np.vstack([fb[:1], fb[1:2] + rng.normal(0, 8, 4)])][trial % 3]
        depth, sigma = pipe._box_depths(b, 0.1, frame_boxes=fb)
        fronts, answered = pipe._depth_order(b, fb, 0.1, q)
        shortcuts += sum(a is not P._ASK for a in answered)
        ref = q.depths_in_boxes(b, 0.1, max_age_s=pipe.cfg.depth_max_age_s, excludes=[fb[f] if f.any() else None for f in fronts])
        np.testing.assert_array_equal(depth, [r.depth if r is not None else np.nan for r in ref])
        np.testing.assert_array_equal(sigma, [r.sigma if r is not None else np.nan for r in ref])
        checked += len(b)
        found += int(np.isfinite(depth).sum())
    assert shortcuts > checked // 3  # the depth order's query answers a good part of them
    assert found > checked // 2  # most boxes hold a robot's returns (not a comparison of empty answers)


def test_a_lost_track_does_not_jump_farther_than_a_robot_can_move():
    """B13 of the benchmark: a track lost for 1.5 s (its covariance says a 10 m gate) took a cluster 8.7 m away and,
    with its undecayed votes, the label of the robot tracked there. A robot moves at most ``vmax`` (4.5 m/s)."""
    tk = Tracker3D()
    tr = _coasting(tk, (14.1, 10.1), "blue_4")
    tr.t_seen = tr.t = 1.0
    tr.P = np.diag([4.0, 4.0, 9.0, 9.0])  # what 1.5 s of coasting leaves
    far = np.array([19.7, 3.5])  # 8.6 m: more than 0.8 + 4.5 * 1.5 m
    near = np.array([16.0, 8.0])  # 2.8 m: within reach
    g = tk._gate(tr, np.array([0.05, 0.05]), np.array([2.5, 2.5]))
    assert np.linalg.norm(far - tr.x[:2]) > g[0] and np.linalg.norm(near - tr.x[:2]) < g[1]
    assert g[0] == pytest.approx(0.8 + 4.5 * 1.5 + 3 * np.hypot(0.05, 0.1))
    fresh = _coasting(tk, (5.0, 5.0), "red_1")  # a track measured now keeps its covariance gate
    fresh.t_seen = fresh.t = 2.5
    assert tk._gate(fresh, np.array([0.05]), np.array([2.5]))[0] == pytest.approx(0.8 + 3 * np.sqrt(0.05**2 + 0.05**2))


def test_tick_detector_two_workers_keep_tick_order():
    import time

    class Rec:
        last_timings_ms: dict = {}

        def __call__(self, images, cameras=None):
            time.sleep(0.02 * (int(images[0][0, 0]) % 2))  # odd ticks slower: they finish after the next one
            return [[Detection(np.array([0.0, 0.0, 10.0, 10.0]), f"blue_{int(im[0, 0])}", 0.9)] for im in images]

    frames = [CameraFrame(0.1 * k, f"{k}", (lambda k=k: np.full((4, 4), float(k))), k) for k in range(8)]
    td = TickDetector(recogniser=Rec(), ahead=True, workers=2)
    got = [td(tick).views[0][3][0].label for tick in td.frames(group_by_time({"cam0": frames}))]
    assert got == [f"blue_{k}" for k in range(8)]


def test_band_scores_a_robot_whose_only_entry_is_a_prediction_is_not_located_on_the_map():
    """benchmarks.multicam: 'all' scores the label's entry (one with evidence before a prediction of that label);
    'sent' only the entries on the referee map — a coasting prediction 2 m off counts in 'all', not in 'sent'."""
    from radarcal.runtime.evaluation import band_scores

    truth = {"f0": {"robots": [{"label": "blue_1", "p_field": [20.0, 5.0, 0.0], "visible_in": ["cam0"]},
                               {"label": "blue_2", "p_field": [22.0, 9.0, 0.0], "visible_in": ["cam0"]},
                               {"label": "red_1", "p_field": [5.0, 5.0, 0.0], "visible_in": ["cam0"]}]}}  # fmt: skip
    res = [{"frame": "f0", "robots": [{"label": "blue_1", "x": 20.4, "y": 5.0, "source": "predicted"},  # an outranked copy, 0.4 m off
                                      {"label": "blue_1", "x": 20.1, "y": 5.0, "source": "lidar"},
                                      {"label": "blue_2", "x": 24.0, "y": 9.0, "source": "predicted"},  # coasting alone, 2 m off
                                      {"label": "red_1", "x": 5.0, "y": 5.0, "source": "lidar"}]}]  # near: not in the band
    b = band_scores(res, truth, (0.0, 5.0), 15.0, seen_by="cam0")
    assert b["robot_frames"] == 2 and b["located"] == 2 and b["located_sent"] == 1
    assert b["correct_label_pct"] == 50.0 and b["correct_label_sent_pct"] == 50.0
    assert b["median_sent_m"] == pytest.approx(0.1) and b["p95_sent_m"] == pytest.approx(0.1)
    assert b["p95_m"] == pytest.approx(0.1 + 0.95 * 1.9)  # blue_1's measured entry (0.1 m), blue_2's prediction (2 m)
    assert b["twice_pct"] == 100.0 and b["twice_labelled_pct"] == 0.0  # blue_1 twice, once on the map
    # every visible robot-frame, an unlocated one as inf: 95 % of the two need both located -> blue_2's 2 m, and inf
    # on the map (blue_2 is not there); within 0.3 m: blue_1 only, in both
    assert b["p95_visible_m"] == pytest.approx(2.0) and b["p95_visible_sent_m"] == np.inf
    assert b["within_0p3_pct"] == 50.0 and b["within_0p3_sent_pct"] == 50.0
    assert b["tail_sources"] == {"lidar cam0": (1, pytest.approx(0.1), 0.0), "predicted cam0": (1, pytest.approx(2.0), 1.0)}


def test_band_scores_p95_over_visible_robot_frames_counts_a_missing_one_as_inf():
    """20 visible robot-frames, 19 located at 0.01 .. 0.19 m: the 95th of 20 is the 19th -> 0.19 m; one more
    missing (18 located) -> inf; the located-only p95 does not see the misses."""
    from radarcal.runtime.evaluation import band_scores

    def scores(n_located):
        truth = {f"f{i}": {"robots": [{"label": "blue_1", "p_field": [20.0, 5.0, 0.0], "visible_in": ["cam0"]}]} for i in range(20)}
        res = [{"frame": f"f{i}", "robots": [{"label": "blue_1", "x": 20.0 + 0.01 * (i + 1), "y": 5.0, "source": "lidar"}] if i < n_located else []} for i in range(20)]
        return band_scores(res, truth, (0.0, 5.0), 15.0, seen_by="cam0")

    assert scores(19)["p95_visible_m"] == pytest.approx(0.19) and scores(20)["p95_visible_m"] == pytest.approx(0.19)
    assert scores(18)["p95_visible_m"] == np.inf and scores(18)["p95_m"] < 0.19

"""Tracker3D confirmation of a track born of one cluster and then kept by box fixes (issue #15 round 4)."""

import numpy as np

from radarcal.runtime.tracks import CONFIRMED, TENTATIVE, Tracker3D


def _one_cluster_then_boxes(neighbour: bool, n_boxes: int) -> str:
    tk = Tracker3D()
    if neighbour:  # a confirmed robot 1 m away: a pile-up
        o = tk._new_lidar(np.array([11.0, 5.0, 0.0]), 0.05, 0.0, False, None, None, np.r_[11.0, 5.0, 11.0, 5.0])
        o.state, o.n_lidar = CONFIRMED, 5
    tr = tk._new_lidar(np.array([10.0, 5.0, 0.0]), 0.05, 0.0, False, None, None, np.r_[10.0, 5.0, 10.0, 5.0])
    for k in range(n_boxes):
        t = 0.033 * (k + 1)
        if neighbour:
            o.t_seen = o.t_lidar = t
        tk.update_box("blue_3", np.array([10.0, 5.0]), 0.1, t, 0.0, "depth", tr)
        tk.step(t)
    return tr.state


def test_a_one_cluster_track_boxed_three_times_is_confirmed():
    assert _one_cluster_then_boxes(False, 2) == TENTATIVE
    assert _one_cluster_then_boxes(False, 3) == CONFIRMED


def test_in_a_pile_up_it_needs_ten_box_fixes():
    assert _one_cluster_then_boxes(True, 9) == TENTATIVE
    assert _one_cluster_then_boxes(True, 10) == CONFIRMED


def _merged_first_cluster_then_robot(first_off_m: float) -> tuple[np.ndarray, float, float]:
    """A robot standing at (10, 5): its first cluster is ``first_off_m`` off (merged with a neighbour), the next ones
    on it (10 Hz clusters, output at 30 Hz). Returns the velocity after the second cluster, the worst output error
    over the next 0.5 s, and the track's envelope width."""
    tk = Tracker3D()
    hull = lambda c: (np.r_[c - 0.25, 0.0], np.r_[c + 0.25, 0.45])  # noqa: E731
    robot = np.array([10.0, 5.0])
    first = robot + np.array([first_off_m, 0.0])
    centres = [first] + [robot] * 6
    worst, v2 = 0.0, None
    for k, c in enumerate(centres):
        tc = 0.05 + 0.1 * k
        tk.update_clusters(np.r_[c, 0.0][None], np.array([0.08]), np.array([tc]), np.array([False]), np.array([[0.5, 0.5, 0.45]]), [hull(c)], tc)
        for s in range(3):
            tk.step(tc + 0.06 + s / 30)
            if k >= 1:
                worst = max(worst, float(np.linalg.norm(tk.tracks[0].x[:2] - robot)))
        if k == 1:
            v2 = tk.tracks[0].x[2:].copy()
    env = tk.tracks[0].envelope
    return v2, worst, float(np.max(env[2:] - env[:2]))


def test_a_first_cluster_farther_than_a_robot_can_go_restarts_the_track():
    """0.8 m in 0.1 s is beyond vmax (4.5 m/s) + 3 sigma: the track restarts on the second cluster (velocity 0, the
    robot's own envelope) instead of reading the jump as a velocity at vmax and overshooting for several sweeps; a
    0.2 m first-cluster error is an ordinary update."""
    v2, worst, env = _merged_first_cluster_then_robot(0.8)
    assert len(Tracker3D().tracks) == 0 and np.linalg.norm(v2) < 0.1 and worst < 0.05 and env < 0.55
    v2, worst, env = _merged_first_cluster_then_robot(0.2)
    assert np.linalg.norm(v2) > 0.5 and env > 0.65  # updated: the 0.2 m is taken as motion (and the envelope keeps it)

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

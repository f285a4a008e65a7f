"""Replay scoring: the p95 that counts missing robot-frames as infinitely wrong."""

from __future__ import annotations

import warnings

import numpy as np

from radarcal.runtime.evaluation import _p95_with_missing


def test_p95_with_missing_is_numpys_percentile_without_missing_and_inf_when_it_falls_among_them():
    e = np.random.default_rng(0).uniform(0.0, 1.0, 99)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # np.percentile warned (inf - inf) and gave NaN here
        assert np.isclose(_p95_with_missing(e, 99), np.percentile(e, 95))
        # 99 of 100 located: rank 94.05 lies between two located errors
        s = np.sort(e)
        assert np.isclose(_p95_with_missing(e, 100), s[94] + 0.05 * (s[95] - s[94]))
        # 19 of 20 located: rank 18.05 lies between the largest error and a missing one
        assert _p95_with_missing(e[:19], 20) == np.inf
        assert _p95_with_missing(e[:10], 11) == np.inf  # rank 9.5: numpy gave NaN (inf - inf * 0.5)
        assert _p95_with_missing(e[:5], 10) == np.inf  # rank 8.55 between two missing ones: numpy gave NaN
        assert _p95_with_missing(e[:0], 0) is None

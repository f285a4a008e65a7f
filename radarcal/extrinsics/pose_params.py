"""The 6 pose parameters of an increment around a pose (``rx ry rz`` rotation vector, rad; ``tx ty tz``, m) and the
cost profile along each of them. Light on purpose (numpy only): the report draws profiles without importing a solver."""

from __future__ import annotations

import numpy as np

__all__ = ["PARAM_NAMES", "parameter_profiles"]

PARAM_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


def parameter_profiles(cost, x0: np.ndarray, half_widths, n: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate ``cost(x0 + d e_i)`` for d on a symmetric grid of ``n`` steps per parameter.

    Returns (offsets (P, n), costs (P, n)). ``cost`` takes a full parameter vector (e.g. the 6-vector
    rx ry rz tx ty tz of a pose perturbation) and returns a scalar."""
    x0 = np.asarray(x0, float).ravel()
    hw = np.asarray(half_widths, float).ravel()
    if hw.size != x0.size:
        raise ValueError(f"{hw.size} half widths for {x0.size} parameters")
    offsets = np.linspace(-1.0, 1.0, n)[None, :] * hw[:, None]
    costs = np.empty_like(offsets)
    for i in range(x0.size):  # a few dozen cost evaluations, each vectorised over all matches
        for j, d in enumerate(offsets[i]):
            x = x0.copy()
            x[i] += d
            costs[i, j] = float(cost(x))
    return offsets, costs

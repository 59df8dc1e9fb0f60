"""Each frame as a mix of the actor's own expressions: the bounded least-squares weights
of the calibration's basis (one row per step found in the ROM take) that best give the
frame's features."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

# Ridge on each step's weight, relative to the basis row's squared norm: keeps a step the
# frame does not show at 0 rather than trading it against its neighbours.
RIDGE = 0.02
MAX_WEIGHT = 1.5  # a step may be shown past its ROM hold (the take is not always the extreme)
ITERATIONS = 150
CHUNK = 4096


def step_weights(features: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(F, K) float64 weights in [0, MAX_WEIGHT] minimizing ``|w B - x|^2 + RIDGE sum_k
    |B_k|^2 w_k^2`` per frame (accelerated projected gradient), ``features`` (F, D), ``basis`` (K, D)."""
    # The matrices are small (F x K, K ~ 25): BLAS threads only add synchronisation, which on
    # a loaded 2-core machine made a 42 s take's weights take 3-5 s instead of 0.3 s.
    with threadpool_limits(limits=1, user_api="blas"):
        return _step_weights(features, basis)


def _step_weights(features: np.ndarray, basis: np.ndarray) -> np.ndarray:
    basis = np.asarray(basis, np.float64)
    norms = np.maximum((basis * basis).sum(1), 1e-12)
    gram = basis @ basis.T + np.diag(RIDGE * norms)
    step = 1.0 / float(np.linalg.eigvalsh(gram)[-1])
    out = np.empty((len(features), len(basis)))
    for s in range(0, len(features), CHUNK):
        b = np.asarray(features[s:s + CHUNK], np.float64) @ basis.T  # (f, K)
        w = np.clip(np.linalg.solve(gram, b.T).T, 0.0, MAX_WEIGHT)
        y, t = w.copy(), 1.0
        for _ in range(ITERATIONS):
            w_next = np.clip(y - step * (y @ gram - b), 0.0, MAX_WEIGHT)
            t_next = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            y = w_next + ((t - 1.0) / t_next) * (w_next - w)
            w, t = w_next, t_next
        out[s:s + CHUNK] = w
    return out

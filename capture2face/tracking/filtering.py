"""Speed-adaptive One Euro filter (Casiez, Roussel, Vogel 2012), vectorized over coordinates.

Each sample ``x_i`` at time ``t_i`` is smoothed by an exponential low-pass whose cutoff
rises with the (smoothed) speed: ``fc = min_cutoff + beta * |dx/dt|``. Slow motion is
smoothed hard (no jitter while the face holds still), fast motion passes with little lag.
Timestamps drive the smoothing factor, so variable frame rates are handled.

``zero_phase=True`` runs the filter forward, then backward over the result: for offline
clips this cancels the lag of the causal filter (its main cost) at the price of needing
the whole sequence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from capture2face.tracking.head_pose import split_pose


@dataclass
class OneEuro:
    """One Euro filter parameters.

    Attributes:
        min_cutoff: Hz, cutoff at zero speed (lower = smoother still frames).
        beta: 1/unit, how fast the cutoff rises with speed (higher = less lag).
        d_cutoff: Hz, cutoff of the speed estimate.
        zero_phase: forward-backward (no lag, offline) instead of causal.
    """

    min_cutoff: float = 1.0
    beta: float = 0.0
    d_cutoff: float = 1.0
    zero_phase: bool = False


def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray | float:
    tau = 1.0 / (2.0 * np.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class CausalOneEuro:
    """The causal filter as a stream: call it on consecutive blocks of frames; its state
    (last value, smoothed speed, last time) carries over, so blocks give exactly what one
    call on the whole sequence gives."""

    def __init__(self, params: OneEuro, speed_axis: int | None = None):
        self.params = params
        self.speed_axis = speed_axis
        self.prev: np.ndarray | None = None
        self.dprev: np.ndarray | None = None
        self.t_prev = 0.0

    def __call__(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Filter the next block ``x`` (k, ...) at times ``t`` (k,); returns (k, ...)."""
        p, speed_axis = self.params, self.speed_axis
        out = np.empty_like(x)
        if x.shape[0] == 0:
            return out
        first = 0
        if self.prev is None:
            self.prev, self.dprev = x[0].copy(), np.zeros_like(x[0])
            self.t_prev = float(t[0])
            out[0] = self.prev
            first = 1
        prev, dprev, t_prev = self.prev, self.dprev, self.t_prev
        for i in range(first, x.shape[0]):
            ti = float(t[i])
            dt = max(ti - t_prev, 1e-6)
            dx = (x[i] - prev) / dt
            dprev = dprev + _alpha(p.d_cutoff, dt) * (dx - dprev)
            speed = np.abs(dprev)
            if speed_axis is not None:  # one speed per point: isotropic smoothing of a 3D point
                speed = np.linalg.norm(dprev, axis=speed_axis, keepdims=True)
            a = _alpha(p.min_cutoff + p.beta * speed, dt)
            prev = prev + a * (x[i] - prev)
            out[i] = prev
            t_prev = ti
        self.prev, self.dprev, self.t_prev = prev, dprev, t_prev
        return out


def _causal(x: np.ndarray, t: np.ndarray, p: OneEuro, speed_axis: int | None) -> np.ndarray:
    return CausalOneEuro(p, speed_axis)(x, t)


def one_euro(x: np.ndarray, t: np.ndarray, params: OneEuro, speed_axis: int | None = None) -> np.ndarray:
    """Filter ``x`` (F, ...) sampled at times ``t`` (F,) along axis 0.

    Args:
        speed_axis: axis of one sample (counted without the frame axis, negative
            preferred) whose norm is the speed, e.g. -1 for (F, L, 3) points; None filters
            every coordinate on its own speed.

    Returns:
        (F, ...) float64 filtered values.
    """
    x = np.asarray(x, np.float64)
    t = np.asarray(t, np.float64)
    if x.shape[0] < 2:
        return x.copy()
    y = _causal(x, t, params, speed_axis)
    if params.zero_phase:
        y = _causal(y[::-1], -t[::-1], params, speed_axis)[::-1]
    return np.ascontiguousarray(y)


def filter_pose(pose: np.ndarray, t: np.ndarray, params: OneEuro) -> np.ndarray:
    """Filter head poses (F, 4, 4) ``[s R | t]``: translation (cm), rotation, scale.

    The rotation is filtered as a unit quaternion made continuous (each one flipped to the
    hemisphere of its predecessor, so q and -q never average to zero), renormalized after.
    The translation's speed sets the cutoff of all pose components, the quaternion's
    angular speed is added in cm-equivalents at 10 cm (a point on the face surface).
    """
    pose = np.asarray(pose, np.float64)
    _, rot, scale = split_pose(pose)
    q = rot.as_quat()  # (F, 4) x, y, z, w
    sign = np.sign(np.einsum("fi,fi->f", q[1:], q[:-1]))
    sign[sign == 0] = 1.0
    q[1:] *= np.cumprod(sign)[:, None]
    # One vector so that a single speed drives the cutoff: cm for translation, quaternion
    # components scaled so 1 unit of each is about 1 cm of surface motion.
    lever = 20.0  # |dq| ~ angle / 2, times 10 cm lever arm
    vec = np.concatenate([pose[:, :3, 3], q * lever, scale[:, None] * 10.0], axis=1)
    out = one_euro(vec, t, params, speed_axis=-1)
    qf = out[:, 3:7] / np.linalg.norm(out[:, 3:7], axis=1, keepdims=True)
    sf = out[:, 7] / 10.0
    res = np.zeros_like(pose)
    res[:, :3, :3] = Rotation.from_quat(qf).as_matrix() * sf[:, None, None]
    res[:, :3, 3] = out[:, :3]
    res[:, 3, 3] = 1.0
    return res

"""Feature-point retargeting network (Dutreve, Meyer, Bouakaz, VRST 2008).

An RBF network is trained at the neutral frame on pairs (source feature point in head
coordinates -> the target character's feature point). Applied to each frame's source
feature points, it carries the source's expression onto the target's morphology: a
displacement at the source lands where the local shape of the target puts it (a wider
face stretches sideways motion, higher brows move the brow motion up with them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator


def farthest_point_subset(points: np.ndarray, count: int | None, keep: np.ndarray | None = None,
                          min_spacing: float = 0.05) -> np.ndarray:
    """Indices of up to ``count`` well-spread points (greedy farthest-point sampling).

    No two picked points lie closer than ``min_spacing``: coincident feature points (a
    closed mouth puts upper- and lower-lip landmarks on one spot) would make the RBF
    system singular, and near-coincident ones ill-conditioned.

    Args:
        points: (N, 3).
        count: how many to pick at most (None = as many as the spacing allows).
        keep: indices to pick first (where the spacing allows).
    Returns:
        (K,) int64 sorted indices.
    """
    points = np.asarray(points, np.float64)
    n = len(points)
    count = n if count is None else min(count, n)
    order = list(np.unique(keep)) if keep is not None and len(keep) else []
    chosen: list[int] = []
    dist = np.full(n, np.inf)

    def take(i: int) -> None:
        nonlocal dist
        chosen.append(int(i))
        dist = np.minimum(dist, np.linalg.norm(points - points[i], axis=1))

    for i in order:
        if len(chosen) < count and dist[i] >= min_spacing:
            take(i)
    if not chosen:
        take(int(np.argmin(points[:, 1])))
    while len(chosen) < count:
        nxt = int(np.argmax(dist))
        if dist[nxt] < min_spacing:
            break
        take(nxt)
    return np.sort(np.asarray(chosen, np.int64))


@dataclass
class FeatureMap:
    """A trained source -> target feature-point network.

    Attributes:
        source_neutral: (N, 3) source feature points at the neutral frame.
        target_neutral: (N, 3) the target character's feature points at rest.
        network: the RBF interpolant (centres = a subset of ``source_neutral``).
        offset: (N, 3) ``target_neutral - network(source_neutral)``: what makes the
            neutral frame land exactly on the target's neutral even when the network
            smooths (``smoothing > 0``) or uses fewer centres than feature points.
        depth_motion: how much of the source's depth (z) motion away from its neutral
            the network is given (1 = all of it).
    """

    source_neutral: np.ndarray
    target_neutral: np.ndarray
    network: RBFInterpolator
    offset: np.ndarray
    depth_motion: float = 1.0

    def __call__(self, source_points: np.ndarray) -> np.ndarray:
        """Map frames of source feature points onto the target.

        Args:
            source_points: (F, N, 3) or (N, 3) feature points in source head coordinates,
                in the same order as ``source_neutral``.
        Returns:
            (F, N, 3) or (N, 3) float64 target feature points; the source neutral maps to
            ``target_neutral`` exactly.
        """
        pts = np.asarray(source_points, np.float64)
        if self.depth_motion != 1.0:
            pts = self.source_neutral + (pts - self.source_neutral) * np.array([1.0, 1.0, self.depth_motion])
        flat = pts.reshape(-1, 3)
        # One call over all F x N points: the kernel matrix is evaluated in big blocks.
        mapped = self.network(flat).reshape(pts.shape)
        return mapped + self.offset


def fit_feature_map(
    source_neutral: np.ndarray,
    target_neutral: np.ndarray,
    kernel: str = "thin_plate_spline",
    smoothing: float = 0.0,
    epsilon: float | None = None,
    n_centers: int | None = None,
    keep_centers: np.ndarray | None = None,
    depth_motion: float = 1.0,
) -> FeatureMap:
    """Train the network on neutral pairs.

    Args:
        source_neutral: (N, 3) source feature points (head coordinates, neutral frame).
        target_neutral: (N, 3) corresponding target feature points (target at rest).
        kernel, smoothing, epsilon: passed to ``scipy.interpolate.RBFInterpolator``
            (a degree-1 polynomial tail carries the global affine part).
        n_centers: number of RBF centres (a well-spread subset of the feature points;
            None = all but coincident ones). Fewer centres make the per-frame
            evaluation cheaper.
        keep_centers: indices that must be centres (e.g. the bones' landmarks).
        depth_motion: scale of the source's depth motion away from its neutral
            (see :class:`FeatureMap`).
    Returns:
        The :class:`FeatureMap`.
    """
    src = np.asarray(source_neutral, np.float64)
    tgt = np.asarray(target_neutral, np.float64)
    centers = farthest_point_subset(src, n_centers, keep_centers)
    kwargs = {"epsilon": epsilon} if epsilon is not None else {}
    network = RBFInterpolator(
        src[centers], tgt[centers], kernel=kernel, smoothing=smoothing, degree=1, **kwargs
    )
    offset = tgt - network(src)
    return FeatureMap(source_neutral=src, target_neutral=tgt, network=network, offset=offset,
                      depth_motion=float(depth_motion))

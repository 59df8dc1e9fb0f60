"""Bones and morph weights that reproduce the retargeted feature points.

With bones that translate only and convex skinning weights, a landmark vertex v moves by

    p_v = rest_v + sum_m w_m D_mv + sum_i W_vi t_i        (morphs first, then skinning)

so the retargeted feature points are *linear* in the unknowns x = (t_1..t_{B-1}, w_1..w_M)
(bone 0, the head, stays fixed). Each frame solves

    min_x |A x - b_f|^2_W + ridge |x|^2 + temporal |x_f - x_{f-1}|^2,   0 <= w <= 1

optionally with a prior, ``sum_i s_i (x_i - p_fi)^2`` (per-unknown strengths s, per-frame
values p: an ARKit character's morphs pulled towards the clip's ARKit curves), and a
co-activation penalty ``c sum_(i,j) |a_i| |a_j| x_i x_j`` on pairs of antagonist morphs
(|a_i|: the weighted motion of unknown i's column; a raise and a lowering of the same brow
cancel each other's motion, so the fit alone cannot tell a still brow from both at once),
and a cap on the sum of one group of morph weights per frame, ``sum_(i in mix) w_i <= cap_f``
(a viseme set is authored as a mix, one viseme at a time: :mod:`capture2face.retarget.arkit_solve`),

over all frames of a window at once (W: per-feature-point reliability weights; windows:
:mod:`capture2face.retarget.windows`). Why jointly rather than "bone = its mapped landmark": a bone's
landmark vertex moves by sum_i W_vi t_i, not by its own t_i, so copying landmark motion
into bones leaves a systematic error wherever skinning blends neighbouring bones, and the
morph motion at that vertex would be counted twice.

Solving: columns are scaled to unit norm (ridge and temporal terms then weigh every unknown
by the landmark motion it causes). The temporal term couples frames through the path-graph
Laplacian, whose eigenvectors are the DCT-II basis; ``A^T A + ridge`` is diagonalised once,
so the unconstrained solve for all frames is two small matrix products and a DCT pair.
The [0, 1] bounds on morph weights are enforced with ADMM, which reuses the same
factorisation every iteration (only the right-hand side changes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.fft import dct, idct


@dataclass
class LinearRigModel:
    """The rig's feature points as a linear function of bone translations and weights.

    Attributes:
        rest: (N, 3) feature-point rest positions.
        matrix: (3N, n) d(points)/d(x), x = (bone translations of ``free_bones`` (3 each,
            xyz interleaved per bone), then morph weights of ``morphs``).
        free_bones: (Bf,) indices of the bones solved for.
        morphs: (Ms,) indices of the morphs solved for.
        n_rigid: unbounded unknowns between the bones' and the morphs' (an ARKit
            character's residual head motion, :mod:`capture2face.retarget.arkit_solve`).
    """

    rest: np.ndarray
    matrix: np.ndarray
    free_bones: np.ndarray
    morphs: np.ndarray
    n_rigid: int = 0

    @property
    def n_bone_vars(self) -> int:
        return 3 * len(self.free_bones)

    @property
    def n_free_vars(self) -> int:
        """Unknowns without bounds (bones, then rigid motion); the morphs' follow."""
        return self.n_bone_vars + self.n_rigid


def linear_rig_model(rig, vertices: np.ndarray, solve_morphs: bool = True) -> LinearRigModel:
    """Build the linear model of ``rig`` at the given feature-point vertices.

    Args:
        rig: the :class:`~capture2face.rig.face_rig.FaceRig`.
        vertices: (N,) vertex indices of the feature points.
        solve_morphs: include the morph weights as unknowns.
    """
    skin = rig.dense_skin_weights()[vertices].astype(np.float64)  # (N, B)
    n = len(vertices)
    # Bones that move some feature point; bone 0 (head) is fixed by convention.
    free = np.flatnonzero(skin[:, 1:].max(0) > 1e-6) + 1
    cols = [np.kron(skin[:, [b]], np.eye(3)) for b in free]  # each (3N, 3)
    morphs = np.zeros(0, np.int64)
    if solve_morphs and rig.n_morphs:
        deltas = rig.morph_positions[:, vertices].astype(np.float64).reshape(rig.n_morphs, 3 * n)
        morphs = np.flatnonzero(np.abs(deltas).max(1) > 1e-6)
        cols.append(deltas[morphs].T)
    matrix = np.concatenate(cols, axis=1) if cols else np.zeros((3 * n, 0))
    return LinearRigModel(
        rest=rig.vertices[vertices].astype(np.float64), matrix=matrix,
        free_bones=free.astype(np.int64), morphs=morphs,
    )


def _path_laplacian_eigenvalues(frames: int) -> np.ndarray:
    """Eigenvalues of the path graph's Laplacian (eigenvectors: the orthonormal DCT-II)."""
    return 2.0 - 2.0 * np.cos(np.pi * np.arange(frames) / frames)


@dataclass
class LinearSolver:
    """Pre-factorised solver for :class:`LinearRigModel` over all frames of a clip."""

    model: LinearRigModel
    ridge: float
    temporal: float
    morph_ridge: float | None = None
    sparsity: float = 0.0
    axis_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    landmark_weights: np.ndarray | None = None
    rho: float = 1.0
    iterations: int = 200
    tolerance: float = 1e-3
    prior_strength: np.ndarray | None = None
    antagonists: np.ndarray | None = None
    antagonist_strength: float = 0.0
    antagonist_iterations: int = 3
    mix: np.ndarray | None = None  # (G,) bounded unknowns whose weights ``solve``'s cap bounds

    def __post_init__(self) -> None:
        self._cache: dict = {}
        self._cap: np.ndarray | None = None  # the mix's cap of the frames being solved
        # Per-axis weights of the feature-point residual (a tracker's depth is its
        # weakest coordinate) times per-landmark reliability (weights of the squared
        # residual, so the rows take their square roots).
        n_points = len(self.model.rest)
        lw = np.ones(n_points) if self.landmark_weights is None else np.asarray(self.landmark_weights, np.float64)
        self.row_weights = (np.sqrt(lw)[:, None] * np.asarray(self.axis_weights, np.float64)).ravel()
        a = self.model.matrix * self.row_weights[:, None]
        self.scale = np.maximum(np.linalg.norm(a, axis=0), 1e-12)  # (n,)
        self.a = a / self.scale
        n = a.shape[1]
        self.bounded = np.zeros(n, bool)
        self.bounded[self.model.n_free_vars:] = True
        ridge = np.full(n, self.ridge)
        ridge[self.bounded] = self.ridge if self.morph_ridge is None else self.morph_ridge
        if self.prior_strength is not None:  # s (x - p)^2 = (s / scale^2) (z - p scale)^2
            ridge = ridge + np.asarray(self.prior_strength, np.float64) / self.scale**2
        gram = self.a.T @ self.a + np.diag(ridge) + self._coupling(n)
        # Unconstrained factorisation and the ADMM one (rho only on bounded unknowns).
        self.eig_free = np.linalg.eigh(gram)
        self.eig_admm = np.linalg.eigh(gram + self.rho * np.diag(self.bounded.astype(float)))
        # Bounds in scaled units: w = z / scale, 0 <= w <= 1.
        self.upper = np.where(self.bounded, self.scale, np.inf)
        self.lower = np.where(self.bounded, 0.0, -np.inf)

    def _coupling(self, n: int) -> np.ndarray:
        """(n, n) the convex part of the co-activation penalty in scaled units (columns of
        unit norm): ``c z_i z_j = c/4 (z_i + z_j)^2 - c/4 (z_i - z_j)^2``; the concave
        part is linearised at the previous solve (:meth:`solve`)."""
        out = np.zeros((n, n))
        if self.antagonist_strength <= 0 or self.antagonists is None or not len(self.antagonists):
            return out
        i, j = np.asarray(self.antagonists, np.int64).reshape(-1, 2).T
        quarter = 0.25 * float(self.antagonist_strength)
        for u, v in ((i, i), (j, j), (i, j), (j, i)):
            np.add.at(out, (u, v), quarter)
        return out

    def _solve(self, eig, rhs: np.ndarray, pin: int | None) -> np.ndarray:
        """Solve ``G Z + temporal * Z Lt = rhs`` for Z (n, F), G = U diag(s) U^T, with
        ``Z[:, pin] = 0`` exactly when ``pin`` is a frame index.

        In G's eigenbasis every component is an independent 1-D problem over frames,
        diagonal in the DCT basis. Pinning a frame subtracts, per component, the multiple
        of its Green's function (the response to a unit impulse at that frame) that
        cancels the value there: a Lagrange multiplier, exact and O(nF).
        """
        s, u = eig
        frames = rhs.shape[1]
        key = (id(eig), frames, pin)
        if key not in self._cache:  # per factorisation: DCT-domain divisors, Green's function
            denom = s[:, None] + self.temporal * _path_laplacian_eigenvalues(frames)[None, :]
            green = None
            if pin is not None:
                basis_at_pin = dct(np.eye(frames)[pin], type=2, norm="ortho")  # (F,) Q[pin, :]
                green = idct(basis_at_pin[None, :] / denom, type=2, norm="ortho", axis=1)  # (n, F)
                green /= green[:, pin:pin + 1]
            self._cache[key] = (denom, green)
        denom, green = self._cache[key]
        y = idct(dct(u.T @ rhs, type=2, norm="ortho", axis=1) / denom, type=2, norm="ortho", axis=1)
        if green is not None:
            y -= y[:, pin:pin + 1] * green
            y[:, pin] = 0.0
        return u @ y

    def solve(self, points: np.ndarray, pin: int | None = None, prior: np.ndarray | None = None,
              cap: np.ndarray | None = None) -> np.ndarray:
        """Unknowns for every frame.

        Args:
            points: (F, N, 3) target feature points.
            pin: a frame whose unknowns are held at exactly 0 (the neutral frame: rest
                bones, no morphs), whatever the smoothness term says.
            prior: (F, n) values the unknowns are pulled towards with ``prior_strength``
                (None: towards 0, i.e. no prior).
            cap: (F,) the most the weights of the ``mix`` unknowns may sum to, per frame
                (None: no cap).
        Returns:
            (F, n) x = bone translations (cm) then morph weights in [0, 1].
        """
        frames = points.shape[0]
        b = (points - self.model.rest).reshape(frames, -1).T * self.row_weights[:, None]  # (3N, F)
        rhs = self.a.T @ b  # (n, F)
        # L1 prior on the (non-negative) morph weights: a constant pull towards 0.
        rhs[self.bounded] -= self.sparsity
        if prior is not None and self.prior_strength is not None:
            rhs += (np.asarray(self.prior_strength, np.float64) / self.scale)[:, None] * np.asarray(prior, np.float64).T
        self._cap = None if cap is None or self.mix is None or not len(self.mix) else np.asarray(cap, np.float64)
        z = self._bounded_solve(rhs, pin)
        if self.antagonist_strength > 0 and self.antagonists is not None and len(self.antagonists):
            # Convex-concave steps: the co-activation penalty's concave part, linearised at
            # the last solve; each step lowers the penalised objective.
            i, j = np.asarray(self.antagonists, np.int64).reshape(-1, 2).T
            for _ in range(self.antagonist_iterations):
                pull = 0.25 * float(self.antagonist_strength) * (z[i] - z[j])
                linear = np.zeros_like(rhs)
                np.add.at(linear, i, pull)
                np.add.at(linear, j, -pull)
                z = self._bounded_solve(rhs + linear, pin)
        return (z / self.scale[:, None]).T

    def _bounded_solve(self, rhs: np.ndarray, pin: int | None) -> np.ndarray:
        """(n, F) scaled unknowns of ``rhs``, the morphs within their bounds."""
        z = self._solve(self.eig_free, rhs, pin)
        if self.bounded.any() and self._violates(z):
            z = self._admm(rhs, z, pin)
        return np.clip(z, self.lower[:, None], self.upper[:, None])

    def _violates(self, z: np.ndarray) -> bool:
        zb = z[self.bounded]
        if (zb < -1e-9).any() or (zb > self.upper[self.bounded, None] + 1e-9).any():
            return True
        return self._cap is not None and bool((self._mix_sum(z) > self._cap + 1e-9).any())

    def _mix_sum(self, z: np.ndarray) -> np.ndarray:
        """(F,) the ``mix`` unknowns' weights (unscaled) summed, of scaled unknowns z (n, F)."""
        return (z[self.mix] / self.scale[self.mix, None]).sum(0)

    def _project(self, y: np.ndarray) -> np.ndarray:
        """(nb, F) the bounded unknowns ``y`` (scaled) projected onto their box and, with a
        cap, onto the ``mix``'s capped sum."""
        lo, hi = self.lower[self.bounded, None], self.upper[self.bounded, None]
        v = np.clip(y, lo, hi)
        if self._cap is None:
            return v
        rows = np.searchsorted(np.flatnonzero(self.bounded), self.mix)
        v[rows] = capped_box(y[rows], self.scale[self.mix], self._cap)
        return v

    def _admm(self, rhs: np.ndarray, z0: np.ndarray, pin: int | None) -> np.ndarray:
        """Box-constrained solve: split the bounded unknowns into z (smooth) = v (boxed)."""
        v = self._project(z0[self.bounded])
        dual = np.zeros_like(v)
        z = z0
        for _ in range(self.iterations):
            r = rhs.copy()
            r[self.bounded] += self.rho * (v - dual)
            z = self._solve(self.eig_admm, r, pin)
            v_old = v
            v = self._project(z[self.bounded] + dual)
            dual += z[self.bounded] - v
            primal = np.abs(z[self.bounded] - v).max()
            change = np.abs(v - v_old).max()
            if max(primal, change) < self.tolerance:
                break
        z = z.copy()
        z[self.bounded] = v
        return z


def capped_box(y: np.ndarray, scale: np.ndarray, cap: np.ndarray, steps: int = 40) -> np.ndarray:
    """(k, F) the Euclidean projection of scaled unknowns ``y`` (k, F) onto ``0 <= y_i <=
    scale_i`` with ``sum_i y_i / scale_i <= cap_f``: weights ``y / scale`` in [0, 1] summing to
    at most ``cap`` (F,). It is ``clip(y_i - lam_f / scale_i, 0, scale_i)``, ``lam_f >= 0``
    found by bisection where the box alone sums past the cap."""
    s = scale[:, None]
    v = np.clip(y, 0.0, s)
    over = (v / s).sum(0) > cap
    if not over.any():
        return v
    yo, co = y[:, over], np.maximum(cap[over], 0.0)
    lo, hi = np.zeros(over.sum()), np.maximum((yo * s).max(0), 0.0)  # at hi every weight is 0
    for _ in range(steps):
        lam = 0.5 * (lo + hi)
        above = (np.clip(yo - lam / s, 0.0, s) / s).sum(0) > co
        lo, hi = np.where(above, lam, lo), np.where(above, hi, lam)
    v[:, over] = np.clip(yo - hi / s, 0.0, s)
    return v

"""Rotation maths shared by the rig, the renderer's camera, the synthetic truth and the
exporters (glTF, Live Link): plain NumPy, no GL and no glTF, so any stage can import it.

Head coordinates (docs/ARCHITECTURE.md): +x towards the subject's left, +y up, +z out of
the face.
"""

from __future__ import annotations

import numpy as np


def rotation_ypr(angles_deg: np.ndarray) -> np.ndarray:
    """(..., 3) yaw, pitch, roll in degrees -> (..., 3, 3) rotations
    ``Rz(roll) @ Ry(yaw) @ Rx(pitch)``.

    Positive yaw turns +z towards +x, positive pitch tilts +z up towards +y, positive roll
    turns +x towards +y.
    """
    y, p, r = np.moveaxis(np.radians(np.asarray(angles_deg, np.float64)), -1, 0)
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    one, zero = np.ones_like(y), np.zeros_like(y)

    def mat(*rows):
        return np.stack([np.stack(row, -1) for row in rows], -2)

    rx = mat((one, zero, zero), (zero, cp, sp), (zero, -sp, cp))
    ry = mat((cy, zero, sy), (zero, one, zero), (-sy, zero, cy))
    rz = mat((cr, -sr, zero), (sr, cr, zero), (zero, zero, one))
    return rz @ ry @ rx


def nearest_rotation(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) matrices -> (..., 3, 3) nearest rotations (SVD: scale and shear
    removed; a reflection becomes the nearest proper rotation). ``m`` must be finite."""
    m = np.asarray(m, np.float64)
    flat = m.reshape(-1, 3, 3)
    u, _, vt = np.linalg.svd(flat)
    r = u @ vt
    flip = np.linalg.det(r) < 0  # a reflection is no rotation: take the nearest one
    u[flip, :, 2] *= -1.0
    r[flip] = u[flip] @ vt[flip]
    return r.reshape(m.shape)


def rotation_part(head_pose: np.ndarray) -> np.ndarray:
    """(F, 4, 4) head -> camera transforms (or (F, 3, 3) matrices) -> (F, 3, 3) nearest
    rotations (:func:`nearest_rotation`). Frames whose matrix is non-finite or singular
    (never tracked) get the identity."""
    m = np.asarray(head_pose, np.float64)[:, :3, :3].copy()
    finite = np.isfinite(m).all(axis=(1, 2))
    m[~finite] = np.eye(3)
    bad = ~finite | (np.abs(np.linalg.det(m)) < 1e-9)
    m[bad] = np.eye(3)
    return nearest_rotation(m)


def quaternion_matrix(q) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion ``q`` (x, y, z, w, glTF's order)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def quaternions(r: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations -> (F, 4) unit quaternions (x, y, z, w, glTF's order),
    sign-continuous so LINEAR (slerp) playback takes the short way."""
    # Shepperd's method, vectorized: pick the largest of w, x, y, z for stability.
    tr = np.trace(r, axis1=1, axis2=2)
    diag = np.stack([r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]], 1)
    q = np.zeros((len(r), 4))
    case = np.argmax(np.concatenate([tr[:, None], diag], 1), axis=1)
    for c in range(4):  # 4 formula cases, each applied to all frames at once
        s = case == c
        if not s.any():
            continue
        rs = r[s]
        if c == 0:
            w = np.sqrt(np.maximum(1.0 + tr[s], 1e-12)) * 2
            q[s] = np.stack([(rs[:, 2, 1] - rs[:, 1, 2]) / w, (rs[:, 0, 2] - rs[:, 2, 0]) / w,
                             (rs[:, 1, 0] - rs[:, 0, 1]) / w, 0.25 * w], 1)
        else:
            i = c - 1
            j, k = (i + 1) % 3, (i + 2) % 3
            w = np.sqrt(np.maximum(1.0 + rs[:, i, i] - rs[:, j, j] - rs[:, k, k], 1e-12)) * 2
            out = np.zeros((s.sum(), 4))
            out[:, i] = 0.25 * w
            out[:, j] = (rs[:, j, i] + rs[:, i, j]) / w
            out[:, k] = (rs[:, k, i] + rs[:, i, k]) / w
            out[:, 3] = (rs[:, k, j] - rs[:, j, k]) / w
            q[s] = out
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    # Sign continuity: flip a quaternion whose dot with the previous one is negative.
    flips = np.concatenate([[False], np.einsum("ij,ij->i", q[1:], q[:-1]) < 0])
    q *= np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)[:, None]
    return q


def head_rotations(head_pose: np.ndarray) -> np.ndarray:
    """(F, 4, 4) head -> camera transforms (or (F, 3, 3) matrices) -> (F, 4) unit
    quaternions (x, y, z, w) of their rotation part (:func:`rotation_part`), sign-continuous
    (:func:`quaternions`). Non-finite poses become the identity."""
    return quaternions(rotation_part(head_pose))


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale, rotation (3, 3) and shift (3,) of the least-squares similarity
    ``target ~ scale * rotation @ source + shift`` of points (N, 3) (Umeyama)."""
    ms, mt = source.mean(0), target.mean(0)
    a, b = source - ms, target - mt
    u, sv, vt = np.linalg.svd(b.T @ a)
    d = np.ones(3)
    d[2] = np.sign(np.linalg.det(u @ vt)) or 1.0
    rot = u @ np.diag(d) @ vt
    scale = float((sv * d).sum() / max((a * a).sum(), 1e-12))
    return scale, rot, mt - scale * rot @ ms

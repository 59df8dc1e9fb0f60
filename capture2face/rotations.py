"""Rotation maths shared by the rig, the renderer's camera, the synthetic truth and the
exporters: plain NumPy, no GL and no glTF, so any stage can import it.

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

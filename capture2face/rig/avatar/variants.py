"""The default avatar's built-in variants: other morphologies with the same topology, bones
and morphs."""

from __future__ import annotations

import numpy as np

from capture2face.rig import features

VARIANTS = ("default", "wide")


def variant_shape(v: np.ndarray, variant: str) -> np.ndarray:
    """Reshape the canonical vertices (468, 3) for a variant; topology is untouched."""
    if variant == "default":
        return v.copy()
    out = v.astype(np.float64).copy()
    x, y = out[:, 0], out[:, 1]
    out[:, 0] = x * 1.15
    out[:, 1] += 0.5 * features.smoothstep((y - 3.2) / 1.2)  # brows and forehead up
    out[:, 1] -= 0.5 * features.smoothstep((-5.5 - y) / 2.5)  # longer chin
    nose = np.exp(-((x / 1.3) ** 2 + ((y + 0.5) / 2.0) ** 2))
    out[:, 2] += 0.3 * nose  # longer nose
    return out

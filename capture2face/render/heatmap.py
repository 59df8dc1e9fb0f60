"""The heat-map colour map (Turbo, polynomial fit by R. Du) shared by the influence view
and compare.mp4."""

from __future__ import annotations

import numpy as np

_RED = np.array([0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943])
_GREEN = np.array([0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604])
_BLUE = np.array([0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973])
_COEFFS = np.stack([_RED, _GREEN, _BLUE], axis=1)  # (6, 3): powers 0..5 x RGB


def heatmap(values: np.ndarray) -> np.ndarray:
    """(H, W) values in [0, 1] (clipped) -> (H, W, 3) uint8 sRGB colours, dark blue -> red."""
    x = np.clip(np.asarray(values, np.float64), 0.0, 1.0)
    powers = x[..., None] ** np.arange(6)  # (..., 6)
    rgb = np.clip(powers @ _COEFFS, 0.0, 1.0)
    return np.round(rgb * 255.0).astype(np.uint8)

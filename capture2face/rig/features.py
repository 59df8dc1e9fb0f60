"""Where the wrinkle areas of a face are, in texture space.

The canonical mesh's UV layout is close to a frontal projection (about 0.049 UV per cm in
both directions, subject's left at u > 0.5), so areas are defined as smooth 2-D shapes
around the UVs of tracker landmarks. One definition serves the zone masks (painted in
UV space), the per-vertex region weights (the same functions at vertex UVs) and the
placement of the procedural wrinkles in ``maps.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES
from capture2face.topology import BROW_LEFT, BROW_RIGHT, EYE_OUTER_CORNERS, MOUTH_CORNERS


@dataclass(frozen=True)
class FeatureLayout:
    """Feature points in UV space (u, v), derived from the canonical landmark UVs.

    Left/right are the subject's: left is u > 0.5.
    """

    forehead: tuple  # centre, semi-axes
    glabella: tuple
    crows_left: tuple
    crows_right: tuple
    nasolabial_left: tuple  # segment start (by the nose wing), end (beside the mouth corner)
    nasolabial_right: tuple
    chin: tuple
    eye_corner_left: np.ndarray  # outer eye corners
    eye_corner_right: np.ndarray
    brow_top: np.ndarray  # (N, 2) upper edges of both brows, sorted by u
    hairline: np.ndarray  # (2,) top of the forehead on the midline


def feature_layout(landmark_uvs: np.ndarray) -> FeatureLayout:
    """Build the layout from (>= 468, 2) landmark UVs of the canonical mesh."""
    uv = np.asarray(landmark_uvs, np.float64)
    top, brow_l, brow_r = uv[10], uv[BROW_LEFT[1]], uv[BROW_RIGHT[1]]
    brow_inner_l, brow_inner_r, nose_root = uv[BROW_LEFT[0]], uv[BROW_RIGHT[0]], uv[168]
    corner_l, corner_r = uv[EYE_OUTER_CORNERS[1]], uv[EYE_OUTER_CORNERS[0]]
    wing_l, wing_r, mouth_l, mouth_r = uv[278], uv[48], uv[MOUTH_CORNERS[1]], uv[MOUTH_CORNERS[0]]
    lip_low, chin_low = uv[17], uv[152]
    brow_v = 0.5 * (brow_l[1] + brow_r[1])
    forehead = ((0.5, 0.5 * (top[1] + brow_v) + 0.01),
                (0.92 * (brow_l[0] - brow_r[0]) / 2 + 0.06, 0.5 * (brow_v - top[1]) - 0.005))
    glabella = ((0.5, 0.5 * (brow_inner_l[1] + nose_root[1])),
                (0.42 * (brow_inner_l[0] - brow_inner_r[0]), 0.55 * (nose_root[1] - brow_inner_l[1]) + 0.02))

    def crows(c, s):
        return (c[0] + s * 0.042, c[1] + 0.004), (0.036, 0.058)

    def naso(w, m, s):
        # The fold runs from just above-lateral of the nose wing to below-lateral of the mouth corner.
        return (w[0] + s * 0.022, w[1] - 0.004), (m[0] + s * 0.036, m[1] + 0.04)

    # Upper brow edges, outer to inner: right brow, then the left's mirror landmarks.
    brow_top = uv[[70, 63, 105, 66, 107, 336, 296, 334, 293, 300]]
    chin = ((0.5, lip_low[1] + 0.47 * (chin_low[1] - lip_low[1])), (0.07, 0.36 * (chin_low[1] - lip_low[1])))
    return FeatureLayout(
        forehead=forehead, glabella=glabella,
        crows_left=crows(corner_l, 1), crows_right=crows(corner_r, -1),
        nasolabial_left=naso(wing_l, mouth_l, 1), nasolabial_right=naso(wing_r, mouth_r, -1),
        chin=chin, eye_corner_left=corner_l, eye_corner_right=corner_r,
        brow_top=brow_top[np.argsort(brow_top[:, 0])], hairline=top,
    )


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def ellipse_mask(u, v, centre, axes, soft: float = 0.45) -> np.ndarray:
    """1 inside the ellipse shrunk by ``soft``/2, falling smoothly to 0 at ``1 + soft/2``."""
    r = np.hypot((u - centre[0]) / axes[0], (v - centre[1]) / axes[1])
    return smoothstep((1.0 + soft / 2 - r) / soft)


def segment_distance(u, v, a, b) -> tuple[np.ndarray, np.ndarray]:
    """Distance from (u, v) to segment a-b and the clamped parameter t in [0, 1]."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b - a
    t = np.clip(((u - a[0]) * d[0] + (v - a[1]) * d[1]) / (d @ d), 0.0, 1.0)
    return np.hypot(u - a[0] - t * d[0], v - a[1] - t * d[1]), t


def band_mask(u, v, seg, half_width: float = 0.03, soft: float = 0.5) -> np.ndarray:
    dist, t = segment_distance(u, v, *seg)
    # Taper the band at both ends so the zone has no hard cut across it.
    ends = smoothstep(t / 0.15) * smoothstep((1 - t) / 0.15) * 0.5 + 0.5
    return smoothstep((1.0 + soft / 2 - dist / half_width) / soft) * ends


def zone_fields(u: np.ndarray, v: np.ndarray, layout: FeatureLayout) -> np.ndarray:
    """(8, *u.shape) float64 masks in [0, 1], in ``ZONE_NAMES`` order."""
    u, v = np.asarray(u, float), np.asarray(v, float)
    forehead = ellipse_mask(u, v, *layout.forehead, soft=0.5)
    left = smoothstep((u - 0.5) / 0.04 + 0.5)
    zones = {
        "forehead_left": forehead * left,
        "forehead_right": forehead * (1.0 - left),
        "glabella": ellipse_mask(u, v, *layout.glabella),
        "crows_feet_left": ellipse_mask(u, v, *layout.crows_left),
        "crows_feet_right": ellipse_mask(u, v, *layout.crows_right),
        "nasolabial_left": band_mask(u, v, layout.nasolabial_left),
        "nasolabial_right": band_mask(u, v, layout.nasolabial_right),
        "chin": ellipse_mask(u, v, *layout.chin),
    }
    return np.stack([zones[name] for name in ZONE_NAMES])


def region_fields(u: np.ndarray, v: np.ndarray, layout: FeatureLayout) -> np.ndarray:
    """(R, *u.shape) float64 memberships in ``REGION_NAMES`` order (forehead = both halves)."""
    z = dict(zip(ZONE_NAMES, zone_fields(u, v, layout)))
    z["forehead"] = z["forehead_left"] + z["forehead_right"]
    return np.stack([np.clip(z[name], 0.0, 1.0) for name in REGION_NAMES])

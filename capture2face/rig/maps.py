"""Procedural textures of the default avatar, painted in UV space with NumPy.

Every map is H x W = 1024 x 1024, UV origin top-left (texel row = v * H). Features are
placed from the canonical landmark UVs through ``features.feature_layout``.

Normal maps (base and wrinkle) are tangent space, OpenGL style: x along the tangent
(+u, texture right), y along the bitangent, which points along -v (texture up, the
face's up), z out of the surface. They are built from height fields h(row, col) by
central differences: ``n = normalize(-dh/du, +dh/dv, 1)`` (the + because the bitangent
is -v), and stored as ``round(n * 127.5 + 127.5)`` uint8. A flat texel is (128, 128, 255).

Texture-space layout besides the skin: two eye discs (top corners, sclera / iris / pupil
painted around the disc centre, which is each eyeball's front pole) and a mouth-interior
disc (bottom-left corner); the skin's UVs never reach the corners.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path
from capture2face.rig import features
from capture2face.topology import LIDS_LEFT, LIDS_RIGHT

# Teeth: widths (cm, along the arch from the midline) of the incisors, canine and
# premolars of one side; what shows between open lips.
TOOTH_WIDTHS = (0.85, 0.68, 0.78, 0.7, 0.7)

SIZE = 1024
WRINKLE_STRENGTH = 6.0  # texels of height per unit of the wrinkle height fields

EYE_TEXTURE_CENTRES = {"R": (0.085, 0.085), "L": (0.915, 0.085)}
EYE_TEXTURE_RADIUS = 0.08
EYE_VISIBLE_THETA = 0.95  # polar angle (rad) of the eyeball front that gets most of the disc
MOUTH_TEXTURE_CENTRE = (0.085, 0.915)
MOUTH_TEXTURE_RADIUS = 0.07
# Bottom-right corner: the teeth (u along the arch, v from the front root over the edge
# to the back root, per row) and the tongue.
TEETH_U = (0.845, 0.985)
TEETH_V = {"upper": (0.865, 0.905), "lower": (0.91, 0.95)}
TONGUE_UV = (0.85, 0.98, 0.955, 0.99)  # u0, u1, v0, v1
# Top band between the eye discs: the head shell (u around the face's edge, v from the
# edge towards the back of the neck); bottom band: the ears (a disc each: front inside,
# back in the outer ring).
HEAD_U, HEAD_V = (0.18, 0.82), (0.004, 0.096)
EAR_U = {"R": (0.2, 0.25), "L": (0.26, 0.31)}
EAR_V = (0.955, 0.995)
HAIR_SRGB = np.array([58.0, 44.0, 36.0])
TEETH_SRGB = np.array([232.0, 222.0, 200.0])
GUM_SRGB = np.array([190.0, 104.0, 108.0])
TONGUE_SRGB = np.array([196.0, 104.0, 108.0])

SKIN_SRGB = np.array([222.0, 172.0, 148.0])
LIP_SRGB = np.array([178.0, 88.0, 88.0])
BROW_SRGB = np.array([78.0, 56.0, 44.0])
IRIS_SRGB = np.array([82.0, 108.0, 128.0])
SCLERA_SRGB = np.array([236.0, 232.0, 224.0])


def eye_uv_radius(theta: np.ndarray) -> np.ndarray:
    """Radius in the eye disc (UV units) of an eyeball point at polar angle ``theta``
    from the front pole: the visible front gets 85% of the disc, the rest is squeezed
    into the outer ring."""
    theta = np.asarray(theta, float)
    front = 0.85 * theta / EYE_VISIBLE_THETA
    back = 0.85 + 0.15 * (theta - EYE_VISIBLE_THETA) / (np.pi - EYE_VISIBLE_THETA)
    return EYE_TEXTURE_RADIUS * np.where(theta <= EYE_VISIBLE_THETA, front, back)


def eye_theta_of_radius(r_uv: np.ndarray) -> np.ndarray:
    """Inverse of :func:`eye_uv_radius`."""
    x = np.asarray(r_uv, float) / EYE_TEXTURE_RADIUS
    return np.where(x <= 0.85, x / 0.85 * EYE_VISIBLE_THETA,
                    EYE_VISIBLE_THETA + (x - 0.85) / 0.15 * (np.pi - EYE_VISIBLE_THETA))


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    c = (np.arange(size) + 0.5) / size
    return np.meshgrid(c, c)  # u (columns), v (rows)


def height_to_normal(height: np.ndarray, strength: float = 1.0) -> np.ndarray:
    """(H, W) height (texel units) -> (H, W, 3) float unit tangent-space normals.

    Central differences; x = -dh/du, y = +dh/dv (bitangent = -v), z = 1, normalized."""
    dv, du = np.gradient(height.astype(np.float64))
    n = np.stack([-strength * du, strength * dv, np.ones_like(du)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def encode_normals(n: np.ndarray) -> np.ndarray:
    return np.clip(np.round(n * 127.5 + 127.5), 0, 255).astype(np.uint8)


def decode_normals(img: np.ndarray) -> np.ndarray:
    """uint8 (..., 3) -> float unit normals."""
    n = img.astype(np.float64) / 127.5 - 1.0
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)


def _band_noise(shape, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian-filtered white noise scaled to unit standard deviation."""
    n = ndimage.gaussian_filter(rng.standard_normal(shape), sigma, mode="wrap")
    return n / max(n.std(), 1e-12)


def _groove(dist: np.ndarray, width: float) -> np.ndarray:
    """Profile of a wrinkle across its line: a groove with soft shoulders (1 at centre)."""
    x = dist / width
    return np.exp(-x * x) - 0.25 * np.exp(-((np.abs(x) - 1.6) ** 2) / 0.5)


def _coverage(uvs: np.ndarray, triangles: np.ndarray, size: int) -> np.ndarray:
    """(size, size) bool: texels covered by the given UV triangles."""
    mask = np.zeros((size, size), np.uint8)
    pts = np.round(uvs[triangles] * size * 16 - 0.5 * 16).astype(np.int32)  # 4 fractional bits
    cv2.fillPoly(mask, list(pts), 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


# ---------------------------------------------------------------------------------------
# Wrinkle height fields


def _segment_param(u, v, a, b):
    """Signed perpendicular distance (left of a->b positive) and parameter t (unclamped)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b - a
    length = np.hypot(*d)
    t = ((u - a[0]) * d[0] + (v - a[1]) * d[1]) / (length * length)
    signed = ((u - a[0]) * d[1] - (v - a[1]) * d[0]) / length
    return signed, t


def _window(t: np.ndarray, fade: float = 0.2) -> np.ndarray:
    """1 in the middle of [0, 1], fading to 0 at both ends."""
    return features.smoothstep(t / fade) * features.smoothstep((1.0 - t) / fade)


def _brow_curve(layout: features.FeatureLayout) -> np.ndarray:
    """Coefficients (c0, c2, c4) of ``v = c0 + c2 x^2 + c4 x^4``, ``x = u - 0.5``: a smooth,
    symmetric least-squares fit to the upper edges of both brows (their arch)."""
    x, v = layout.brow_top[:, 0] - 0.5, layout.brow_top[:, 1]
    return np.linalg.lstsq(np.stack([np.ones_like(x), x**2, x**4], 1), v, rcond=None)[0]


# Forehead furrows, bottom to top: (height above the brows as a fraction of the brow ->
# hairline distance on the midline, how much of the brow's arch the line keeps, half
# length in u, depth). Widely spaced and broad, so they survive the texture's
# minification at video sizes; lower lines follow the brows, upper ones flatten out.
_FURROWS = ((0.16, 0.85, 0.235, 0.9), (0.33, 0.65, 0.235, 1.0), (0.5, 0.45, 0.22, 0.95), (0.67, 0.3, 0.19, 0.8))
FURROW_WIDTH = 0.0105  # UV; ~0.22 cm on the face
FURROW_DEPTH = 2.6  # texels of height per unit of depth, before WRINKLE_STRENGTH


def stretch_height(u, v, layout: features.FeatureLayout, rng: np.random.Generator) -> np.ndarray:
    """Long horizontal forehead furrows (brows raised) that follow the brows' arch."""
    c0, c2, c4 = _brow_curve(layout)
    x = u - 0.5
    arch = c2 * x**2 + c4 * x**4  # the brow curve's shape, 0 on the midline
    span = c0 - layout.hairline[1]  # brow top to hairline on the midline (UV)
    h = np.zeros_like(u)
    for k, (rise, keep, half, depth) in enumerate(_FURROWS):
        half *= 0.95 + 0.1 * rng.random()
        wobble = 0.002 * np.sin(2 * np.pi * u * (4 + 3 * rng.random()) + rng.random() * 6.3)
        line_v = c0 - rise * span + keep * arch + wobble
        t = (u - (0.5 - half)) / (2 * half)
        # Depth varies along the line, and real furrows break near the midline on some lines.
        along = 0.8 + 0.2 * np.sin(2 * np.pi * u * (3 + 2 * rng.random()) + rng.random() * 6.3)
        gap = 1.0 - (0.7 * np.exp(-(((u - 0.5 - 0.02 * rng.standard_normal()) / 0.025) ** 2)) if k % 2 else 0.0)
        h -= FURROW_DEPTH * depth * along * _groove(v - line_v, FURROW_WIDTH) * _window(t, 0.22) * gap
    return h


def _mirror_u(f):
    """Evaluate a left-side feature function on the right side as well (u -> 1 - u)."""
    return lambda u, v, *a: f(u, v, *a) + f(1.0 - u, v, *a)


def compress_height(u, v, layout: features.FeatureLayout, rng: np.random.Generator) -> np.ndarray:
    """Vertical glabella lines, crow's feet, nasolabial folds and chin dimpling."""
    h = np.zeros_like(u)
    # Glabella: two (and a faint third) near-vertical lines between the brows, fanning
    # slightly apart towards the top.
    (gu, gv), (gau, gav) = layout.glabella
    for offset, depth, length in ((-0.36, 1.0, 1.0), (0.36, 1.0, 0.95), (0.05, 0.45, 0.6)):
        top_v, bot_v = gv - 0.9 * gav * length, gv + 0.75 * gav * length
        t = (v - top_v) / (bot_v - top_v)
        line_u = gu + offset * gau * (1.0 + 0.25 * (1.0 - t))
        h -= depth * 1.6 * _groove(u - line_u, 0.0065) * _window(t, 0.25)

    # Crow's feet: lines fanning out from the outer eye corner.
    def crows(uu, vv):
        out = np.zeros_like(uu)
        corner = layout.eye_corner_left
        for angle, length, depth in ((-38, 0.045, 0.75), (-15, 0.055, 1.1), (8, 0.06, 1.25), (30, 0.05, 1.0)):
            a = np.deg2rad(angle)
            start = corner + 0.014 * np.array([np.cos(a), np.sin(a)])
            end = corner + (0.014 + length) * np.array([np.cos(a), np.sin(a)])
            d, t = _segment_param(uu, vv, start, end)
            out -= depth * _groove(d, 0.0052) * _window(t, 0.3)
        return out

    h += _mirror_u(lambda uu, vv: crows(uu, vv))(u, v)

    # Nasolabial folds: a deep curved groove with the cheek bulging over it.
    def naso(uu, vv):
        a, b = (np.asarray(p, float) for p in layout.nasolabial_left)
        d, t = _segment_param(uu, vv, a, b)
        bow = 0.012 * np.sin(np.pi * np.clip(t, 0, 1))  # bowed out towards the cheek
        # Positive d is on the left of a->b, the cheek side for the subject's left fold.
        side = np.sign(((b - a)[1]) * 1.0) or 1.0
        dist = d - side * bow
        fold = -1.6 * np.exp(-(dist / 0.0075) ** 2) + 0.9 * np.exp(-((dist * side - 0.015) / 0.012) ** 2)
        return fold * _window(t, 0.25)

    h += _mirror_u(naso)(u, v)

    # Chin dimpling (peau d'orange): band-pass bumps under the chin mask.
    (ccu, ccv), (cau, cav) = layout.chin
    mask = features.ellipse_mask(u, v, (ccu, ccv), (cau, cav), soft=0.6)
    bumps = _band_noise(u.shape, 3.0, rng) - 0.5 * _band_noise(u.shape, 7.0, rng)
    h += 0.3 * bumps * mask
    return h


def pore_height(u, v, rng: np.random.Generator) -> np.ndarray:
    """Fine skin detail: pores (small pits, larger and denser on nose and cheeks) over a
    faint micro-relief."""
    shape = u.shape
    centre = np.exp(-(((u - 0.5) / 0.16) ** 2 + ((v - 0.56) / 0.12) ** 2))  # nose and cheeks
    density = 0.012 + 0.02 * centre
    seeds = (rng.random(shape) < density).astype(np.float64) * (0.6 + 0.8 * rng.random(shape))
    pits = ndimage.gaussian_filter(seeds, 1.0) * (1.0 + 0.6 * centre)
    micro = _band_noise(shape, 1.2, rng)
    return -6.0 * pits + 0.12 * micro


# ---------------------------------------------------------------------------------------
# Albedo


def _fill(size: int, polygon_uv: np.ndarray, blur: float) -> np.ndarray:
    mask = np.zeros((size, size), np.float32)
    pts = np.round(np.asarray(polygon_uv) * size * 16).astype(np.int32)
    cv2.fillPoly(mask, [pts], 1.0, shift=4)
    return ndimage.gaussian_filter(mask, blur) if blur else mask


def _albedo(u, v, landmark_uvs, layout, rng, eye_iris_theta: dict) -> np.ndarray:
    size = u.shape[0]
    lm = landmark_uvs
    colour = np.broadcast_to(SKIN_SRGB, u.shape + (3,)).astype(np.float64).copy()
    # Low-frequency tone variation and a little blotchiness.
    colour *= 1.0 + 0.035 * _band_noise(u.shape, 40, rng)[..., None] + 0.012 * _band_noise(u.shape, 4, rng)[..., None]
    # Redness: cheeks, nose tip, chin.
    red = (0.55 * np.exp(-(((np.abs(u - 0.5) - 0.19) / 0.06) ** 2 + ((v - 0.56) / 0.06) ** 2))
           + 0.45 * np.exp(-(((u - 0.5) / 0.04) ** 2 + ((v - 0.53) / 0.035) ** 2))
           + 0.2 * np.exp(-(((u - 0.5) / 0.06) ** 2 + ((v - 0.86) / 0.04) ** 2)))
    colour += red[..., None] * np.array([6.0, -16.0, -12.0])
    # Around the eyes: slightly darker, cooler skin.
    for c in (lm[LIDS_RIGHT[0]], lm[LIDS_LEFT[0]]):  # the upper lids' middles
        ring = np.exp(-(((u - c[0]) / 0.07) ** 2 + ((v - c[1] - 0.008) / 0.04) ** 2))
        colour += ring[..., None] * np.array([-14.0, -16.0, -6.0])
    # Lips.
    outer_upper = [61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291]
    outer_lower = [375, 321, 405, 314, 17, 84, 181, 91, 146]
    lips = _fill(size, lm[outer_upper + outer_lower], 2.0)
    lip_tone = LIP_SRGB * (1.0 + 0.05 * _band_noise(u.shape, 2.0, rng)[..., None])
    colour = colour * (1 - lips[..., None]) + lip_tone * lips[..., None]
    # Brows: hair strokes inside the brow outlines.
    brow_r = [70, 63, 105, 66, 107, 55, 65, 52, 53, 46]
    brow_l = [300, 293, 334, 296, 336, 285, 295, 282, 283, 276]
    brows = _fill(size, lm[brow_r], 3.0) + _fill(size, lm[brow_l], 3.0)
    strokes = ndimage.gaussian_filter(rng.standard_normal(u.shape), (0.6, 3.5))  # elongated along u
    hair = np.clip(brows * (0.9 + 0.35 * strokes / strokes.std()), 0, 1)
    colour = colour * (1 - 0.85 * hair[..., None]) + BROW_SRGB * 0.85 * hair[..., None]
    # Eyes.
    for side, (ecu, ecv) in EYE_TEXTURE_CENTRES.items():
        r = np.hypot(u - ecu, v - ecv)
        inside = r < EYE_TEXTURE_RADIUS * 1.05
        theta = eye_theta_of_radius(r)
        iris_t = eye_iris_theta[side]
        rel = theta / iris_t
        phi = np.arctan2(v - ecv, u - ecu)
        streaks = 1.0 + 0.18 * np.sin(phi * 37 + 3 * np.sin(phi * 5)) * (rel > 0.35)
        iris = IRIS_SRGB * streaks[..., None] * (1.0 - 0.35 * features.smoothstep((rel - 0.75) / 0.25))[..., None]
        sclera = SCLERA_SRGB - features.smoothstep((rel - 1.5) / 2.0)[..., None] * np.array([10.0, 40.0, 40.0])
        eye = np.where((rel < 1.0)[..., None], iris, sclera)
        eye = np.where((rel < 0.38)[..., None], np.array([12.0, 10.0, 10.0]), eye)
        edge = features.smoothstep((rel - 0.96) / 0.08)[..., None]  # soft limbus
        eye = np.where((rel < 1.04)[..., None] & (rel >= 0.96)[..., None], iris * (1 - edge) + sclera * edge, eye)
        colour = np.where(inside[..., None], eye, colour)
    # Mouth interior: dark red, darker deeper in.
    r = np.hypot(u - MOUTH_TEXTURE_CENTRE[0], v - MOUTH_TEXTURE_CENTRE[1]) / MOUTH_TEXTURE_RADIUS
    mouth = (np.array([110.0, 42.0, 46.0])[None, None] * (1.0 - 0.75 * np.clip(r, 0, 1))[..., None])
    colour = np.where((r < 1.1)[..., None], mouth, colour)
    colour = _teeth_and_tongue_albedo(u, v, colour)
    return np.clip(np.round(colour), 0, 255).astype(np.uint8)


def _teeth_and_tongue_albedo(u, v, colour: np.ndarray) -> np.ndarray:
    """Paint the teeth (ivory crowns, dark gaps between teeth, gums at the roots; the
    TOOTH_WIDTHS along the arch) and the tongue into ``colour`` (H, W, 3)."""
    u0, u1 = TEETH_U
    ends = sum(TOOTH_WIDTHS)
    arc = ((u - u0) / (u1 - u0) * 2.0 - 1.0) * ends  # arc length from the midline (cm)
    bounds = np.concatenate([[0.0], np.cumsum(TOOTH_WIDTHS)])
    gap_dist = np.min(np.abs(np.abs(arc)[..., None] - bounds[None, None]), axis=-1)
    gap = np.exp(-((gap_dist / 0.035) ** 2))
    inside_u = (u >= u0 - 0.002) & (u <= u1 + 0.002)
    for v0, v1 in TEETH_V.values():
        frac = (v - v0) / (v1 - v0)  # 0 front root, 0.4 edge, 1 back root
        band = inside_u & (frac >= -0.05) & (frac <= 1.05)
        root = np.minimum(frac, 1.0 - frac)  # 0 at the roots, 0.5 at the edge
        gum = 1.0 - features.smoothstep((root - 0.06) / 0.08)
        tooth = TEETH_SRGB * (1.0 - 0.1 * (1.0 - 2.0 * np.clip(root, 0, 0.5)))[..., None]
        tooth = tooth * (1.0 - 0.6 * gap[..., None])
        col = tooth * (1.0 - gum[..., None]) + GUM_SRGB * gum[..., None]
        colour = np.where(band[..., None], col, colour)
    tu0, tu1, tv0, tv1 = TONGUE_UV
    x = (u - 0.5 * (tu0 + tu1)) / (0.5 * (tu1 - tu0))
    y = (v - 0.5 * (tv0 + tv1)) / (0.5 * (tv1 - tv0))
    tongue = (x * x + y * y) <= 1.3
    shade = TONGUE_SRGB * (1.0 - 0.25 * np.exp(-(x / 0.12) ** 2))[..., None]  # the median groove
    return np.where(tongue[..., None], shade, colour)


def _head_albedo(u, v, albedo: np.ndarray, hair_grid: np.ndarray, edge_uvs: np.ndarray,
                 rng: np.random.Generator, shadow_grid: np.ndarray | None = None) -> np.ndarray:
    """Paint the head shell's band (skin, short hair combed back where ``hair_grid``
    says) and the ears' discs (skin, darker in the hollow) into ``albedo``. The skin
    starts at the colour of the face's texture along its edge (``edge_uvs``: the face
    vertex under each column of the shell) and fades to the edge's mean tone."""
    colour = albedo.astype(np.float64)
    rows, cols = hair_grid.shape
    size = albedo.shape[0]
    texel = np.clip((edge_uvs * size).astype(int), 0, size - 1)
    edge = ndimage.uniform_filter(colour, (9, 9, 1))[texel[:, 1], texel[:, 0]]  # (cols, 3), pores averaged out
    fade = features.smoothstep(np.arange(rows) / 5.0)[:, None, None]
    tone = edge[None] * (1 - fade) + edge.mean(0) * fade  # (rows, cols, 3)
    if shadow_grid is not None:
        tone = tone * (1.0 - shadow_grid[..., None])
    band = (u >= HEAD_U[0] - 0.003) & (u <= HEAD_U[1] + 0.003) & (v >= HEAD_V[0] - 0.003) & (v <= HEAD_V[1] + 0.003)
    ring = np.clip((v - HEAD_V[0]) / (HEAD_V[1] - HEAD_V[0]), 0, 1) * (rows - 1)
    col = np.clip((u - HEAD_U[0]) / (HEAD_U[1] - HEAD_U[0]), 0, 1) * (cols - 1)
    hair = ndimage.map_coordinates(hair_grid.astype(np.float64), [ring, col], order=1, mode="nearest")
    # Strands along v (the rings run from the face backwards): noise stretched that way.
    strands = ndimage.gaussian_filter(rng.standard_normal(u.shape), (3.0, 0.7), mode="wrap")
    strands /= max(strands.std(), 1e-12)
    hair_tone = HAIR_SRGB * (1.0 + 0.22 * strands)[..., None]
    skin = np.stack([ndimage.map_coordinates(tone[..., c], [ring, col], order=1, mode="nearest") for c in range(3)], -1)
    head = skin * (1 - hair[..., None]) + hair_tone * hair[..., None]
    colour = np.where(band[..., None], head, colour)
    for u0, u1 in EAR_U.values():
        c = np.array([0.5 * (u0 + u1), 0.5 * (EAR_V[0] + EAR_V[1])])
        r = np.hypot(u - c[0], v - c[1]) / (0.5 * (EAR_V[1] - EAR_V[0]))  # 0.5: the rim
        inside = r <= 1.05
        hollow = np.exp(-((r - 0.18) / 0.12) ** 2)  # the concha, in shadow
        ear = edge.mean(0) * (1.0 - 0.3 * hollow)[..., None] + np.array([8.0, -10.0, -8.0]) * (r < 0.5)[..., None]
        colour = np.where(inside[..., None], ear, colour)
    return np.clip(np.round(colour), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------------------------


def build_maps(landmark_uvs: np.ndarray, uvs: np.ndarray, triangles: np.ndarray, material: np.ndarray,
               eye_iris_theta: dict, size: int = SIZE, seed: int = 7, head_hair: np.ndarray | None = None,
               head_edge_uvs: np.ndarray | None = None, head_shadow: np.ndarray | None = None
               ) -> dict[str, np.ndarray]:
    """All textures of the avatar.

    Args:
        landmark_uvs: (468, 2) canonical landmark UVs (feature placement).
        uvs, triangles, material: the rig's (V, 2), (T, 3), (V,) (skin coverage).
        eye_iris_theta: {"R": rad, "L": rad} polar angle of each iris rim on its eyeball.
        head_hair: (rings, columns) hair coverage of the head shell's vertex grid (its UVs
            span ``HEAD_U`` x ``HEAD_V``), or None for no head; ``head_edge_uvs`` (columns,
            2): the UVs of the face's edge vertex under each column; ``head_shadow`` (rings,
            columns): how much darker the shell's skin is painted (the jaw's shadow).
    Returns:
        dict with "albedo" (H, W, 3), "normal", "stretch", "compress" (H, W, 3) uint8
        normal maps, "zones" (H, W, 8) uint8.
    """
    rng = np.random.default_rng(seed)
    u, v = _grid(size)
    layout = features.feature_layout(landmark_uvs)
    skin_tris = triangles[(material[triangles] == 0).all(axis=1)]
    skin = ndimage.binary_dilation(_coverage(uvs, skin_tris, size), iterations=4)

    # Heights are in texel units; a texel is ~0.2 mm on the face.
    stretch = stretch_height(u, v, layout, rng) * skin
    compress = compress_height(u, v, layout, rng) * skin
    pores = pore_height(u, v, rng) * skin
    if head_hair is not None:
        # The head shell has no pores: they fade out over the last ~0.6 cm of the face's
        # outer edge, so no line shows where the face meets the head.
        face = ndimage.binary_fill_holes(_coverage(uvs, skin_tris, size))
        pores = pores * features.smoothstep(ndimage.distance_transform_edt(face) / (0.03 * size))
    zones = features.zone_fields(u, v, layout) * skin
    albedo = _albedo(u, v, landmark_uvs, layout, rng, eye_iris_theta)
    if head_hair is not None:
        albedo = _head_albedo(u, v, albedo, head_hair, head_edge_uvs, rng, head_shadow)
    return {
        "albedo": albedo,
        "normal": encode_normals(height_to_normal(pores, 0.6)),
        "stretch": encode_normals(height_to_normal(ndimage.gaussian_filter(stretch, 0.7), WRINKLE_STRENGTH)),
        "compress": encode_normals(height_to_normal(ndimage.gaussian_filter(compress, 0.7), WRINKLE_STRENGTH)),
        "zones": np.clip(np.round(np.moveaxis(zones, 0, -1) * 255), 0, 255).astype(np.uint8),
    }


def write_maps(rig, directory: str | os.PathLike) -> list[Path]:
    """Write a rig's textures as PNGs: albedo.png, normal.png, wrinkle_<name>.png,
    zones_0.png and zones_1.png (RGBA: zones 0-3 and 4-7). Returns the paths written."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    images = {"albedo.png": rig.albedo, "normal.png": rig.normal_map}
    for name, img in zip(rig.wrinkle_map_names, rig.wrinkle_maps):
        images[f"wrinkle_{name}.png"] = img
    images["zones_0.png"] = rig.zone_masks[..., 0:4]
    images["zones_1.png"] = rig.zone_masks[..., 4:8]
    written = []
    for fname, img in images.items():
        path = directory / fname
        # OpenCV writes BGR(A); our arrays are RGB(A).
        bgr = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA if img.shape[-1] == 4 else cv2.COLOR_RGB2BGR)
        with atomic_path(path) as tmp:
            if not cv2.imwrite(str(tmp), bgr):
                raise CaptureError(f"could not write {path}")
        written.append(path)
    return written

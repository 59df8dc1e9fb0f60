"""NumPy mirror of ``shaders/normal_blend.glsl`` (tests, and baking maps offline)."""

from __future__ import annotations

import numpy as np


def unpack_normal(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 normal-map texels (n * 127.5 + 127.5) -> (..., 3) unit normals."""
    n = np.asarray(rgb, np.float64) / 255.0 * 2.0 - 1.0
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def pd_encode(n: np.ndarray) -> np.ndarray:
    """(..., 3) unit normals -> (..., 2) partial derivatives ``(nx/nz, ny/nz)`` (Jimenez)."""
    n = np.asarray(n, np.float64)
    return n[..., :2] / np.maximum(n[..., 2:3], 1e-3)


def pd_decode(d: np.ndarray) -> np.ndarray:
    """(..., 2) partial derivatives -> (..., 3) unit normals ``normalize(dx, dy, 1)``."""
    d = np.asarray(d, np.float64)
    n = np.concatenate([d, np.ones(d.shape[:-1] + (1,))], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def oat_blend(w: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Oat's detail blend of wrinkle normal ``w`` over base ``n``:
    ``normalize(w.x + n.x, w.y + n.y, w.z * n.z)``."""
    w, n = np.asarray(w, np.float64), np.asarray(n, np.float64)
    out = np.concatenate([w[..., :2] + n[..., :2], w[..., 2:3] * n[..., 2:3]], axis=-1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def wrinkle_pd_layers(maps: np.ndarray) -> np.ndarray:
    """Wrinkle normal maps as the renderer samples them: partial derivatives, two maps per
    RGBA layer (Jimenez: derivatives filter and blend linearly, so they are encoded once
    here instead of per pixel).

    Args:
        maps: (K, H, W, 3) uint8 tangent-space normal maps.
    Returns:
        (ceil(K / 2), H, W, 4) float16: map 2j in RG and map 2j + 1 in BA of layer j (a
        missing last map is flat: zeros).
    """
    maps = np.asarray(maps)
    k, h, w, _ = maps.shape
    out = np.zeros(((k + 1) // 2, h, w, 4), np.float16)
    for i in range(k):  # one map at a time keeps the temporaries small
        # pd_encode(unpack_normal(t)) in float32: the normalization cancels in x/z and y/z
        # except for the clamp of a grazing z.
        n = maps[i].astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
        length = np.sqrt(np.einsum("...c,...c->...", n, n))[..., None]
        z = np.maximum(n[..., 2:3], np.float32(1e-3) * length)
        out[i // 2, ..., 2 * (i % 2):2 * (i % 2) + 2] = n[..., :2] / z
    return out

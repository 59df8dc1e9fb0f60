"""The default avatar's wrinkle maps and zone masks baked into a character's UV space.

Each texel of a character face triangle is a point on the character's surface (its
triangle's vertices, interpolated); the avatar fitted onto the character's landmarks is
searched for the surface point nearest it, and the texel takes the avatar's map at that
point's UV. The baked pattern is so a function of the 3D surface: every UV island, seam and
triangle of the character sees one continuous field, at the avatar's fold width scaled by
the fit (the head's size). Each texel averages the avatar's map over its footprint there
(no aliasing into steps where the character's texels are coarser than the folds: 1.5-5 of
the avatar's on the shared heads), and each face island is extended by a
:data:`GUTTER` of its border texels so that bilinear and mipmapped sampling at its edges
read the fold, not the flat background.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from capture2face.errors import CaptureError
from capture2face.maths.surface import closest_points
from capture2face.rig.face_rig import FaceRig
from capture2face.rig.maps import decode_normals, encode_normals

GUTTER = 4  # texels each face UV island is extended by (bilinear and mip sampling at its border)
SUPERSAMPLE = 4  # samples a side over each character texel's footprint on the avatar's maps
MAX_SPAN = 6.0  # a triangle whose texel spans this many times the face's median: across a seam
_FLAT = np.array([128, 128, 255], np.uint8)


def bake_maps(rig: FaceRig, avatar: FaceRig, fitted: np.ndarray, rot: np.ndarray,
              face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The avatar's wrinkle maps and zone masks in ``rig``'s UV space over its face triangles
    (flat normals, zero zones elsewhere); maps the character brings are kept.

    Args:
        fitted: (Va, 3) the avatar's vertices fitted onto the character (its rest space).
        rot: (3, 3) the fit's rotation (avatar -> character), for the avatar's tangents.
        face: (V,) bool, the character's face vertices.
    Returns:
        wrinkle maps (K, H, W, 3) in ``rig.wrinkle_map_names`` order, zone masks (H, W, 8).
    Raises:
        CaptureError: the face triangles cover no texel (nothing to bake into).
    """
    H, W = rig.albedo.shape[:2]
    maps, zones = rig.wrinkle_maps.copy(), rig.zone_masks.copy()
    todo = [k for k, n in enumerate(rig.wrinkle_map_names)
            if n in avatar.wrinkle_map_names and (maps[k] == _FLAT).all()]  # keep maps the character brings
    bake_zones = not zones.any()
    tris = rig.triangles[face[rig.triangles].all(1)]
    if not len(tris) or not (todo or bake_zones):
        return maps, zones
    ids, covered = _rasterize(rig.uvs, tris, rig.triangles, H, W)
    ys, xs = np.nonzero(ids >= 0)
    if not len(ys):  # no UVs, all in one point, or outside 0-1: a wrinkle without its map is nothing
        raise CaptureError(f"character '{rig.name}': its face's UVs cover no texel of its texture "
                           "(no TEXCOORD_0, or UVs outside 0-1): no wrinkle maps to bake")
    tri = tris[ids[ys, xs]]  # (N, 3)
    bary = _texel_bary(rig.uvs, tri, xs, ys, W, H)
    askin = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    at, abary, _ = closest_points(fitted, askin, np.einsum("nk,nkc->nc", bary, rig.vertices[tri].astype(np.float64)))
    atri = askin[at]
    auv = np.einsum("nk,nkc->nc", abary, avatar.uvs[atri].astype(np.float64))
    ah, aw = avatar.wrinkle_maps.shape[1:3]
    jac = _uv_jacobians(rig, tris, avatar, fitted, askin, (W, H), (aw, ah))[ids[ys, xs]]
    sample = _sampler(auv * [aw, ah], jac)
    if todo:
        turn = _tangent_turn(rig, tri, bary, avatar, atri, abary, rot)
        for k in todo:
            src = avatar.wrinkle_maps[avatar.wrinkle_map_names.index(rig.wrinkle_map_names[k])]
            n = sample(decode_normals(src).astype(np.float32))  # the mean normal over the texel
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
            maps[k, ys, xs] = encode_normals(turn(n))
            maps[k] = _with_gutter(maps[k], ys, xs, covered)
    if bake_zones:
        zones[ys, xs, :4] = np.rint(sample(avatar.zone_masks[..., :4]))
        zones[ys, xs, 4:8] = np.rint(sample(avatar.zone_masks[..., 4:8]))
        zones = _with_gutter(zones, ys, xs, covered)
    return maps, zones


def _rasterize(uvs: np.ndarray, tris: np.ndarray, every: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) index into ``tris`` of the triangle over each texel centre (-1: none), and
    (H, W) bool: texels any triangle of ``every`` touches (the gutter stays off them)."""
    def corners(t):  # texel centres at +0.5; 4 fractional bits
        return np.rint((uvs[t] * [W, H] - 0.5) * 16).astype(np.int32)

    ids = np.full((H, W), -1, np.int32)
    for t, c in enumerate(corners(tris)):  # per triangle: OpenCV fills one polygon a call
        cv2.fillConvexPoly(ids, c, t, lineType=cv2.LINE_8, shift=4)
    covered = np.zeros((H, W), np.uint8)
    for c in corners(every):
        cv2.fillConvexPoly(covered, c, 1, lineType=cv2.LINE_8, shift=4)
    return ids, covered.astype(bool) | (ids >= 0)


def _texel_bary(uvs: np.ndarray, tri: np.ndarray, xs: np.ndarray, ys: np.ndarray, W: int, H: int) -> np.ndarray:
    """(N, 3) barycentric weights of texel centres (xs, ys) in their UV triangles (N, 3)."""
    p = np.stack([(xs + 0.5) / W, (ys + 0.5) / H], 1)
    a, b, c = (uvs[tri[:, i]].astype(np.float64) for i in range(3))
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    l1 = np.clip((v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den, 0, 1)
    l2 = np.clip((v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den, 0, 1)
    s = np.maximum(l1 + l2, 1.0)  # a texel centre just outside its triangle: onto its edge
    return np.stack([1 - (l1 + l2) / s, l1 / s, l2 / s], 1)


def _uv_jacobians(rig: FaceRig, tris: np.ndarray, avatar: FaceRig, fitted: np.ndarray, askin: np.ndarray,
                  size: tuple[int, int], asize: tuple[int, int]) -> np.ndarray:
    """(T, 2, 2) per face triangle, the avatar texels one character texel step spans
    (columns: a step along u, along v), from its vertices' nearest avatar UVs; 0 where
    that is not a smooth map (a triangle across one of the avatar's UV seams, lips and
    lids, or degenerate in UV)."""
    at, abary, _ = closest_points(fitted, askin, rig.vertices.astype(np.float64))
    auv = np.einsum("nk,nkc->nc", abary, avatar.uvs[askin[at]].astype(np.float64)) * asize
    uv = rig.uvs.astype(np.float64) * size
    own = np.stack([uv[tris[:, 1]] - uv[tris[:, 0]], uv[tris[:, 2]] - uv[tris[:, 0]]], 2)  # (T, 2, 2)
    theirs = np.stack([auv[tris[:, 1]] - auv[tris[:, 0]], auv[tris[:, 2]] - auv[tris[:, 0]]], 2)
    det = own[:, 0, 0] * own[:, 1, 1] - own[:, 0, 1] * own[:, 1, 0]
    ok = np.abs(det) > 1e-6
    jac = np.zeros((len(tris), 2, 2))
    jac[ok] = theirs[ok] @ np.linalg.inv(own[ok])
    scale = np.linalg.norm(jac, axis=(1, 2))
    if ok.any():
        jac[scale > MAX_SPAN * max(float(np.median(scale[ok])), 1e-9)] = 0.0
    return jac


def _sampler(auv_px: np.ndarray, jac: np.ndarray):
    """A function: avatar image (h, w, C) -> (N, C), its mean over each character texel's
    footprint (SUPERSAMPLE^2 bilinear samples about ``auv_px`` (N, 2), in avatar texels,
    spread by ``jac`` (N, 2, 2)): a fold finer than the character's texels fades instead of
    aliasing into steps."""
    steps = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    n = len(auv_px)
    n_rows = -(-n // 1024)  # remap takes maps under 32767 px a side: rows of 1024
    grids = []
    for du in steps:
        for dv in steps:
            at = auv_px + jac @ np.array([du, dv]) - 0.5
            m = np.zeros((2, n_rows * 1024), np.float32)
            m[:, :n] = at.T
            grids.append(m.reshape(2, n_rows, 1024))

    def sample(image: np.ndarray) -> np.ndarray:
        image = np.ascontiguousarray(image)
        total = np.zeros((n_rows * 1024, image.shape[2]), np.float64)
        for mx, my in grids:
            out = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            total += out.reshape(n_rows * 1024, -1)
        return total[:n] / len(grids)

    return sample


def _tangent_turn(rig: FaceRig, tri: np.ndarray, bary: np.ndarray, avatar: FaceRig, atri: np.ndarray,
                  abary: np.ndarray, rot: np.ndarray):
    """A function turning avatar tangent-space normals (N, 3) into the character's at each
    texel: the turn in the character's tangent plane from the avatar's tangent (fitted) to
    the character's, and a mirror where their bitangents disagree; flat stays flat."""
    def at(values, t, b):
        return np.einsum("nk,nkc->nc", b, values[t].astype(np.float64))

    tc, nc = at(rig.tangents[:, :3], tri, bary), at(rig.normals, tri, bary)
    nc /= np.maximum(np.linalg.norm(nc, axis=1, keepdims=True), 1e-12)
    bc = at(rig.tangents[:, 3:4], tri, bary) * np.cross(nc, tc)
    ta = at(avatar.tangents[:, :3], atri, abary) @ np.asarray(rot, np.float64).T
    ta -= np.einsum("nc,nc->n", ta, nc)[:, None] * nc
    cs = np.stack([np.einsum("nc,nc->n", ta, tc), np.einsum("nc,nc->n", ta, bc)], 1)
    cs /= np.maximum(np.linalg.norm(cs, axis=1, keepdims=True), 1e-12)
    mirror = at(avatar.tangents[:, 3:4], atri, abary)[:, 0] * at(rig.tangents[:, 3:4], tri, bary)[:, 0] < 0

    def turn(n: np.ndarray) -> np.ndarray:
        x, y = n[:, 0], np.where(mirror, -n[:, 1], n[:, 1])
        return np.stack([cs[:, 0] * x - cs[:, 1] * y, cs[:, 1] * x + cs[:, 0] * y, n[:, 2]], 1)

    return turn


def _with_gutter(image: np.ndarray, ys: np.ndarray, xs: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """``image`` with the texels within :data:`GUTTER` of the baked ones (ys, xs) that no
    triangle touches set to their nearest baked texel's value."""
    H, W = image.shape[:2]
    y0, y1 = max(ys.min() - GUTTER, 0), min(ys.max() + GUTTER + 1, H)
    x0, x1 = max(xs.min() - GUTTER, 0), min(xs.max() + GUTTER + 1, W)
    baked = np.zeros((y1 - y0, x1 - x0), bool)
    baked[ys - y0, xs - x0] = True
    dist, (iy, ix) = ndimage.distance_transform_edt(~baked, return_indices=True)
    fill = (dist > 0) & (dist <= GUTTER) & ~covered[y0:y1, x0:x1]
    out = image.copy()
    fy, fx = np.nonzero(fill)
    out[fy + y0, fx + x0] = image[iy[fy, fx] + y0, ix[fy, fx] + x0]
    return out

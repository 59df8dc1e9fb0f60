"""The default avatar's wrinkle maps and zone masks baked into a character's UV space.

Each texel of a character face triangle is a point on the character's surface (its
triangle's vertices, interpolated); the avatar fitted onto the character's landmarks is
searched for the surface point nearest it, and the texel takes the avatar's map at that
point's UV. The baked pattern is so a function of the 3D surface: every UV island, seam and
triangle of the character sees one continuous field, at the avatar's fold width scaled by
the fit (the head's size). The avatar's maps are blurred to the character's texel size first
(no aliasing where its texels are coarser), and each face island is extended by a
:data:`GUTTER` of its border texels so that bilinear and mipmapped sampling at its edges
read the fold, not the flat background.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from capture2face.maths.surface import closest_points
from capture2face.rig.face_rig import FaceRig
from capture2face.rig.maps import decode_normals, encode_normals

GUTTER = 4  # texels each face UV island is extended by (bilinear and mip sampling at its border)
WARP_SMOOTHING = 1e-3  # thin-plate smoothing of the landmark warp (inter-ocular units)
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
    if not len(ys):
        return maps, zones
    tri = tris[ids[ys, xs]]  # (N, 3)
    bary = _texel_bary(rig.uvs, tri, xs, ys, W, H)
    askin = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    at, abary, _ = closest_points(fitted, askin, np.einsum("nk,nkc->nc", bary, rig.vertices[tri].astype(np.float64)))
    atri = askin[at]
    auv = np.einsum("nk,nkc->nc", abary, avatar.uvs[atri].astype(np.float64))
    ah, aw = avatar.wrinkle_maps.shape[1:3]
    sigma = 0.5 * _texel_ratio(rig, tris, avatar, fitted, askin, (W, H), (aw, ah))
    sample = _sampler(auv, aw, ah)
    if todo:
        turn = _tangent_turn(rig, tri, bary, avatar, atri, abary, rot)
        for k in todo:
            src = avatar.wrinkle_maps[avatar.wrinkle_map_names.index(rig.wrinkle_map_names[k])]
            if sigma > 0.5:  # the character's texel spans several of the avatar's: low-pass first
                src = encode_normals(decode_normals(cv2.GaussianBlur(src.astype(np.float32), (0, 0), sigma)))
            maps[k, ys, xs] = encode_normals(turn(decode_normals(sample(src))))
            maps[k] = _with_gutter(maps[k], ys, xs, covered)
    if bake_zones:
        zones[ys, xs, :4] = sample(avatar.zone_masks[..., :4])
        zones[ys, xs, 4:8] = sample(avatar.zone_masks[..., 4:8])
        zones = _with_gutter(zones, ys, xs, covered)
    return maps, zones


def warp_to_landmarks(fitted: np.ndarray, source: np.ndarray, target: np.ndarray, iod: float) -> np.ndarray:
    """(Va, 3) the fitted avatar's vertices moved by a smooth (thin-plate, smoothed) field
    that carries its landmarks ``source`` (L, 3) onto the character's ``target`` (L, 3):
    its folds then lie where the character's brows, lids and eye corners are, not where a
    rigid fit puts the avatar's."""
    from scipy.interpolate import RBFInterpolator

    scale = max(iod, 1e-9)  # in inter-ocular distances: the smoothing means the same on any head
    field = RBFInterpolator(source / scale, (target - source) / scale, kernel="thin_plate_spline",
                            smoothing=WARP_SMOOTHING, degree=1)
    return fitted + scale * field(fitted / scale)


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


def _texel_ratio(rig: FaceRig, tris: np.ndarray, avatar: FaceRig, fitted: np.ndarray, askin: np.ndarray,
                 size: tuple[int, int], asize: tuple[int, int]) -> float:
    """How many of the avatar's texels one character texel spans (median over the face):
    the face triangles' areas in avatar texels (their vertices' nearest avatar UVs) over
    their areas in the character's."""
    at, abary, _ = closest_points(fitted, askin, rig.vertices.astype(np.float64))
    auv = np.einsum("nk,nkc->nc", abary, avatar.uvs[askin[at]].astype(np.float64)) * asize
    uv = rig.uvs.astype(np.float64) * size

    def area(x):  # (T, 3, 2) -> (T,)
        e1, e2 = x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])

    own = area(uv[tris])
    ok = own > 1e-9
    if not ok.any():
        return 1.0
    return float(np.sqrt(np.median(area(auv[tris[ok]]) / own[ok])))


def _sampler(auv: np.ndarray, aw: int, ah: int):
    """A function: avatar image (h, w, C) -> (N, C), bilinear at the UVs ``auv`` (N, 2)."""
    n_rows = -(-len(auv) // 1024)  # remap takes maps under 32767 px a side: rows of 1024
    mx = np.zeros(n_rows * 1024, np.float32)
    my = np.zeros(n_rows * 1024, np.float32)
    mx[: len(auv)], my[: len(auv)] = auv[:, 0] * aw - 0.5, auv[:, 1] * ah - 0.5
    mx, my = mx.reshape(n_rows, 1024), my.reshape(n_rows, 1024)

    def sample(image: np.ndarray) -> np.ndarray:
        out = cv2.remap(np.ascontiguousarray(image), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(n_rows * 1024, -1)[: len(auv)]

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

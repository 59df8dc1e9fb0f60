"""The automatic wrinkle bake (capture2face.character.wrinkle_bake) on a head whose UVs are
cut across the forehead: the baked fold pattern is one field on the surface, continuous
across the cut and without steps, on an island of any texel density."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from scipy import ndimage

from capture2face.character.wrinkle_bake import bake_maps
from capture2face.maths.surface import closest_points
from capture2face.rig.maps import decode_normals

FLAT = np.array([128, 128, 255], np.uint8)


def _subdivided(avatar):
    """The avatar's skin with each triangle cut into four at its edges' midpoints: the same
    surface, four times denser than the avatar (as a scanned head is)."""
    skin = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    edges = np.sort(np.concatenate([skin[:, [0, 1]], skin[:, [1, 2]], skin[:, [2, 0]]]), axis=1)
    unique, index = np.unique(edges, axis=0, return_inverse=True)
    mid = avatar.n_vertices + index.reshape(3, -1).T  # (T, 3): the midpoints of edges 01, 12, 20
    a, b, c = skin.T
    ab, bc, ca = mid.T
    tris = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])

    def with_mid(x):
        return np.concatenate([x, 0.5 * (x[unique[:, 0]] + x[unique[:, 1]])]).astype(x.dtype)

    normals = with_mid(avatar.normals)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tangents = with_mid(avatar.tangents)
    tangents[:, 3] = np.sign(tangents[:, 3])
    return SimpleNamespace(vertices=with_mid(avatar.vertices), normals=normals, tangents=tangents,
                           uvs=with_mid(avatar.uvs), triangles=tris, material=np.zeros(len(normals), np.int32),
                           n_vertices=len(normals))


def _split_head(mesh, names: list[str]):
    """The mesh's geometry with its skin cut along a vertical line 1.2 cm right of the
    face's midline: the right part's vertices are copied, and their UVs moved into the
    right half of a 1024 x 2048 atlas at half the texel density. Returns the head (the
    attributes the bake reads), the (original, copy) vertex pairs on the cut."""
    skin = (mesh.material[mesh.triangles] == 0).all(1)
    tris = mesh.triangles[skin]
    right = mesh.vertices[tris].mean(1)[:, 0] > mesh.vertices[mesh.material == 0, 0].mean() + 1.2
    moved = np.unique(tris[right])
    copy = np.full(mesh.n_vertices, -1)
    copy[moved] = mesh.n_vertices + np.arange(len(moved))
    tris = np.concatenate([tris[~right], copy[tris[right]]])

    def both(a):
        return np.concatenate([a, a[moved]])

    uvs = np.concatenate([mesh.uvs * [0.5, 1.0], mesh.uvs[moved] * 0.5 + [0.6, 0.3]]).astype(np.float32)
    head = SimpleNamespace(
        albedo=np.zeros((1024, 2048, 3), np.uint8), wrinkle_map_names=list(names),
        wrinkle_maps=np.broadcast_to(FLAT, (len(names), 1024, 2048, 3)).copy(),
        zone_masks=np.zeros((1024, 2048, 8), np.uint8), triangles=tris.astype(np.int32), uvs=uvs,
        vertices=both(mesh.vertices), normals=both(mesh.normals), tangents=both(mesh.tangents))
    on_cut = np.intersect1d(moved, np.unique(mesh.triangles[skin][~right]))
    return head, np.stack([on_cut, copy[on_cut]], 1)


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, C) ``image`` (H, W, C) at UVs (N, 2), bilinear, as the renderer samples it."""
    h, w = image.shape[:2]
    rows, cols = uv[:, 1] * h - 0.5, uv[:, 0] * w - 0.5
    return np.stack([ndimage.map_coordinates(image[..., c].astype(np.float64), [rows, cols], order=1, mode="nearest")
                     for c in range(image.shape[2])], 1)


@pytest.mark.parametrize("denser", [False, True])
def test_baked_wrinkles_are_continuous_across_a_uv_cut_and_have_no_steps(avatar, denser):
    """Also on a head four times denser than the avatar (each vertex nearest an avatar
    vertex took its UV: ICT's crow's feet drew as cracks)."""
    head, pairs = _split_head(_subdivided(avatar) if denser else avatar, list(avatar.wrinkle_map_names))
    face = np.ones(len(head.vertices), bool)
    maps, zones = bake_maps(head, avatar, avatar.vertices, np.eye(3), face)
    for k, name in enumerate(head.wrinkle_map_names):
        baked = decode_normals(maps[k])
        # The same surface point on both sides of the cut: the same normal (the two
        # islands' tangent frames agree), read as the renderer reads it (bilinear, here at
        # the islands' very edge: the gutter keeps the flat background out).
        a, b = (decode_normals(_bilinear(maps[k], head.uvs[pairs[:, i]])) for i in range(2))
        folded = np.linalg.norm(a[:, :2], axis=1) + np.linalg.norm(b[:, :2], axis=1) > 0.1
        assert folded.sum() >= 5, name  # the cut crosses folds
        gap = np.linalg.norm(a - b, axis=1)
        assert np.median(gap[folded]) < 0.05 and gap.max() < 0.25, (name, np.sort(gap[folded])[-5:])
        # Each texel is the avatar's map where its surface point is (here: the same
        # surface), box-filtered over the texel on the coarser island: no steps, no
        # cracks, the avatar's fold width.
        src = avatar.wrinkle_maps[avatar.wrinkle_map_names.index(name)]
        theirs = decode_normals(src)
        ys, xs = np.nonzero((maps[k] != FLAT).any(-1))
        uv = np.stack([(xs + 0.5) / 2048, (ys + 0.5) / 1024], 1)
        island = uv[:, 0] > 0.55
        own = np.where(island[:, None], (uv - [0.6, 0.3]) / 0.5, uv * [2.0, 1.0])  # the avatar's UV
        coarse = cv2.GaussianBlur(theirs.astype(np.float32), (0, 0), 0.6)  # a 2-texel box, roughly
        want = np.where(island[:, None], _bilinear(coarse, own), _bilinear(theirs, own))
        want /= np.linalg.norm(want, axis=1, keepdims=True)
        err = np.linalg.norm(baked[ys, xs] - want, axis=1)
        inner = _inner(head)
        inside = inner[ys, xs]
        assert np.percentile(err[inside], 99) < 0.12, (name, np.percentile(err[inside], [50, 99]))
        # No step along the folds: neighbouring texels differ no more than the avatar's own
        # neighbouring texels do, times the texels of the avatar's one of them spans (but
        # for a few on the avatar's own UV seams, lids and lips, where its map has two sides).
        theirs_step = _steps(theirs, np.ones(theirs.shape[:2], bool)).max()
        left = inner & (np.arange(2048) < 1024)[None]
        for part, ratio in ((left, 1.0), (inner & ~left, 2.0)):
            steep = _steps(baked, part) > 1.1 * ratio * theirs_step
            assert steep.mean() < 2e-4, (name, ratio, steep.sum())
    assert zones.any()


def _steps(normals: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The largest change of a normal component between each two neighbouring texels of
    ``mask`` (along rows and columns)."""
    rows = np.abs(normals[1:] - normals[:-1]).max(-1)[mask[1:] & mask[:-1]]
    cols = np.abs(normals[:, 1:] - normals[:, :-1]).max(-1)[mask[:, 1:] & mask[:, :-1]]
    return np.concatenate([rows, cols])


def _inner(head) -> np.ndarray:
    """(H, W) bool: texels 2 or more texels inside the head's UV islands (not the gutter,
    nor their rasterized edge)."""
    mask = np.zeros(head.albedo.shape[:2], np.uint8)
    for t in head.triangles:
        cv2.fillConvexPoly(mask, np.rint((head.uvs[t] * [2048, 1024] - 0.5) * 16).astype(np.int32), 1,
                           lineType=cv2.LINE_8, shift=4)
    return cv2.erode(mask, np.ones((5, 5), np.uint8)) > 0


def test_closest_points_on_a_mesh():
    rng = np.random.default_rng(1)
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), -1).reshape(-1, 2)
    vertices = np.concatenate([g, 0.1 * np.sin(g[:, :1])], 1)
    i = np.arange(36).reshape(6, 6)[:-1, :-1].ravel()
    tris = np.concatenate([np.stack([i, i + 1, i + 7], 1), np.stack([i, i + 7, i + 6], 1)])
    p = np.concatenate([rng.uniform(0.5, 4.5, (500, 2)), rng.normal(0, 0.3, (500, 1))], 1)
    tri, bary, dist = closest_points(vertices, tris, p)
    q = np.einsum("nk,nkc->nc", bary, vertices[tris[tri]])
    np.testing.assert_allclose(np.linalg.norm(q - p, axis=1), dist, atol=1e-5)
    assert (bary >= -1e-6).all() and np.allclose(bary.sum(1), 1)
    # No point of the mesh (dense samples of every triangle) is nearer.
    s = np.random.default_rng(2).dirichlet([1, 1, 1], 200)
    dense = np.einsum("sk,tkc->tsc", s, vertices[tris]).reshape(-1, 3)
    nearest = np.min(np.linalg.norm(dense[None] - p[:, None], axis=2), axis=1)
    assert (dist <= nearest + 1e-5).all()

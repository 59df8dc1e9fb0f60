"""Renderer, wrinkle drivers, normal blending, camera and video writer (issue 3)."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES, FaceRig

# ---------------------------------------------------------------------------------------
# A small but complete FaceRig: a curved skin patch (with a UV seam down the middle), an
# eye patch and a mouth-interior patch, 4 translation bones, 2 morphs, 2 reference poses.


def _grid_patch(nx, ny, x_range, y_range, depth_fn):
    xs = np.linspace(*x_range, nx)
    ys = np.linspace(*y_range, ny)
    gx, gy = np.meshgrid(xs, ys)  # rows: y
    pos = np.stack([gx, gy, depth_fn(gx, gy)], -1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    # y grows upwards, x to the subject's left (+x): (a, b, d) is counter-clockwise from +z.
    tris = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return pos, tris, idx


def _ridges(size, axis, freq):
    """Tangent-space normal map of sinusoidal ridges along ``axis`` (0: varies with u)."""
    t = np.linspace(0, 2 * np.pi * freq, size)
    slope = 0.6 * np.cos(t)
    n = np.zeros((size, size, 3))
    if axis == 0:
        n[..., 0] = slope[None, :]
    else:
        n[..., 1] = slope[:, None]
    n[..., 2] = 1.0
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.round(n * 127.5 + 127.5).astype(np.uint8)


def make_test_rig(n=41, tex=128) -> FaceRig:
    depth = lambda x, y: 5.0 - x**2 / 25.0 - y**2 / 70.0  # noqa: E731
    pos, tris, idx = _grid_patch(n, n, (-7, 7), (-9, 9), depth)
    uv = np.stack([(pos[:, 0] + 7) / 14, (9 - pos[:, 1]) / 18], -1)
    # UV seam down the middle column: the right half (x > 0) uses copies of that column
    # whose u is offset, as an unwrap with a cut there would have.
    mid = n // 2
    seam = idx[:, mid]
    copies = np.arange(len(pos), len(pos) + len(seam))
    remap = np.arange(len(pos))
    remap[seam] = copies
    right = (pos[tris, 0] > 1e-6).any(1)
    tris[right] = remap[tris[right]]
    pos = np.concatenate([pos, pos[seam]])
    uv = np.concatenate([uv, uv[seam] + [0.02, 0.0]])
    pids = np.concatenate([np.arange(n * n), seam]).astype(np.int32)
    material = np.zeros(len(pos), np.uint8)
    # Eye: a small patch in front of the skin at (-3, 1.5); mouth interior behind the skin.
    parts = [(pos, tris, uv, material, pids)]
    for mat, centre, dz in ((1, (-3.0, 1.5), 0.3), (2, (0.0, -5.0), -1.5)):
        p, t, _ = _grid_patch(5, 5, (centre[0] - 1, centre[0] + 1), (centre[1] - 0.7, centre[1] + 0.7),
                              lambda x, y: depth(x, y) + dz)
        offset = sum(len(q[0]) for q in parts)
        parts.append((p, t + offset, np.full((len(p), 2), 0.9), np.full(len(p), mat, np.uint8),
                      np.arange(len(p)) + offset + 10_000))
    pos = np.concatenate([q[0] for q in parts]).astype(np.float32)
    tris = np.concatenate([q[1] for q in parts]).astype(np.int32)
    uv = np.concatenate([q[2] for q in parts]).astype(np.float32)
    material = np.concatenate([q[3] for q in parts])
    _, pids = np.unique(np.concatenate([q[4] for q in parts]), return_inverse=True)
    V = len(pos)

    normals = np.stack([2 * pos[:, 0] / 25.0, 2 * pos[:, 1] / 70.0, np.ones(V)], -1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tangent = np.cross([0.0, 1.0, 0.0], normals)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    tangents = np.concatenate([tangent, np.ones((V, 1))], 1)

    bone_rest = np.array([[0, 0, 0], [-3.0, 4.5, 4.5], [3.0, 4.5, 4.5], [0, -6.0, 4.0]], np.float32)
    radius = np.array([np.inf, 4.0, 4.0, 4.0])
    d = np.linalg.norm(pos[:, None, :2] - bone_rest[None, :, :2], axis=2)
    w = np.clip(1 - d / radius, 0, None) ** 2
    w[:, 0] = 0.0
    w[material == 0, 0] = np.clip(1 - w[material == 0, 1:].sum(1), 0, None)
    w[material != 0] = [1, 0, 0, 0]
    w /= w.sum(1, keepdims=True)

    M = 2
    morph_pos = np.zeros((M, V, 3), np.float32)
    morph_pos[0, :, 1] = -1.5 * np.clip(-(pos[:, 1] + 2) / 7, 0, 1)  # jawOpen
    morph_pos[1, :, 1] = 0.8 * np.exp(-((pos[:, 0] ** 2) + (pos[:, 1] - 5) ** 2) / 6)  # browInnerUp
    morph_nrm = np.zeros((M, V, 3), np.float32)
    morph_nrm[0, :, 1] = -0.2 * np.clip(-(pos[:, 1] + 2) / 7, 0, 1)

    pose_bones = np.stack([bone_rest.copy(), bone_rest.copy()])
    pose_bones[0, 1:3, 1] += 1.2  # stretch: brows up
    pose_bones[1, 1:3, 1] -= 0.6  # compress: brows down and in
    pose_bones[1, 1, 0] += 0.5
    pose_bones[1, 2, 0] -= 0.5

    # Zone masks in UV space (forehead left/right, glabella, ...), blocks of the texture.
    zone_masks = np.zeros((tex, tex, 8), np.uint8)
    zone_masks[: tex // 3, : tex // 2, 0] = 255
    zone_masks[: tex // 3, tex // 2:, 1] = 255
    zone_table = np.zeros((M, 8), np.float32)
    zone_table[1, :2] = -1.0  # browInnerUp stretches the forehead

    yy, xx = np.mgrid[0:tex, 0:tex] / tex
    albedo = np.stack([200 + 20 * xx, 150 + 10 * yy, 130 + 0 * xx], -1).astype(np.uint8)
    landmarks = np.full(478, -1, np.int32)
    landmarks[33], landmarks[263] = idx[n // 2, 5], idx[n // 2, n - 6]
    region_weights = np.zeros((len(REGION_NAMES), V), np.float32)
    region_weights[0] = (pos[:, 1] > 3) & (material == 0)

    return FaceRig(
        name="test_patch", vertices=pos, normals=normals.astype(np.float32), uvs=uv,
        tangents=tangents.astype(np.float32), triangles=tris, position_ids=pids.astype(np.int32),
        material=material, landmark_vertices=landmarks,
        bone_names=["head", "brow_left", "brow_right", "jaw"], bone_rest=bone_rest,
        bone_parents=np.array([-1, 0, 0, 0], np.int32), bone_landmarks=np.array([-1, 105, 334, 152], np.int32),
        bone_groups=np.arange(4, dtype=np.int32), skin_joints=np.tile(np.arange(4, dtype=np.int32), (V, 1)),
        skin_weights=w.astype(np.float32), morph_names=["jawOpen", "browInnerUp"], morph_positions=morph_pos,
        morph_normals=morph_nrm, pose_names=["stretch", "compress"], pose_bones=pose_bones,
        pose_morph_weights=np.array([[0, 0.5], [0, 0]], np.float32), pose_maps=np.array([0, 1], np.int32),
        wrinkle_map_names=["stretch", "compress"], albedo=albedo,
        normal_map=np.full((tex, tex, 3), [128, 128, 255], np.uint8),
        wrinkle_maps=np.stack([_ridges(tex, 1, 12), _ridges(tex, 0, 16)]),
        zone_names=list(ZONE_NAMES), zone_masks=zone_masks, zone_table=zone_table,
        region_names=list(REGION_NAMES), region_weights=region_weights,
    )


def cpu_deform(rig: FaceRig, bone_positions, blend_weights) -> np.ndarray:
    """Reference: morph targets, then translation-only linear blend skinning."""
    morphed = rig.vertices.astype(np.float64) + np.einsum("m,mvc->vc", blend_weights, rig.morph_positions)
    offsets = (np.asarray(bone_positions, np.float64) - rig.bone_rest)[rig.skin_joints]  # (V, 4, 3)
    return morphed + np.einsum("vj,vjc->vc", rig.skin_weights, offsets)


@pytest.fixture(scope="session")
def rig() -> FaceRig:
    return make_test_rig()

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
                              lambda x, y, dz=dz: depth(x, y) + dz)
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


def cpu_deform(rig: FaceRig, bone_positions, blend_weights, eye_rotation=None) -> np.ndarray:
    """Reference: morph targets, then translation-only linear blend skinning, then each
    eyeball turned about its centre by Ry(yaw) Rx(pitch) (yaw, pitch in degrees)."""
    morphed = rig.vertices.astype(np.float64) + np.einsum("m,mvc->vc", blend_weights, rig.morph_positions)
    offsets = (np.asarray(bone_positions, np.float64) - rig.bone_rest)[rig.skin_joints]  # (V, 4, 3)
    out = morphed + np.einsum("vj,vjc->vc", rig.skin_weights, offsets)
    if eye_rotation is not None and rig.eye_centres is not None:
        from scipy.spatial.transform import Rotation

        for side in (0, 1):
            yaw, pitch = np.radians(eye_rotation[side])
            r = Rotation.from_euler("YX", [yaw, pitch]).as_matrix()  # intrinsic: Ry(yaw) @ Rx(pitch)
            ids = rig.eye_vertex_side == side
            out[ids] = (out[ids] - rig.eye_centres[side]) @ r.T + rig.eye_centres[side]
    return out


@pytest.fixture(scope="session")
def rig() -> FaceRig:
    return make_test_rig()


RIGS = ["rig", "avatar"]  # the test patch (UV seam, known layout) and the default avatar


# ---------------------------------------------------------------------------------------
# Helpers

from capture2face.camera import framing_pose, project  # noqa: E402
from capture2face.render import FrameState, Renderer, RenderOptions, heatmap  # noqa: E402
from capture2face.render.dynamic import dynamic_wrinkle_weights  # noqa: E402
from capture2face.render.normal_blend import oat_blend, pd_decode, pd_encode  # noqa: E402

SIZE = 256


def random_unit_normals(n, seed, cone=0.6):
    rng = np.random.default_rng(seed)
    v = np.concatenate([rng.uniform(-cone, cone, (n, 2)), np.ones((n, 1))], 1)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def skinned_mask(rig, bones, pose, size, moved, dilate=3):
    """(H, W) bool: pixels covered by triangles with any weight on the ``moved`` bones."""
    import cv2

    dense = rig.dense_skin_weights()[:, moved].sum(1)
    tris = rig.triangles[(dense[rig.triangles] > 0).any(1)]
    pix = project(cpu_deform(rig, bones, np.zeros(rig.n_morphs)), pose, 30.0, size)
    mask = np.zeros((size, size), np.uint8)
    cv2.fillPoly(mask, [np.round(pix[t] * 16).astype(np.int32) for t in tris], 1, shift=4)
    return cv2.dilate(mask, np.ones((2 * dilate + 1,) * 2, np.uint8)).astype(bool)


@pytest.fixture(scope="session")
def view(rig):
    return framing_pose(rig, yaw=10.0, pitch=5.0)


# ---------------------------------------------------------------------------------------
# Deformation (NumPy, per frame; the GL only transforms)


@pytest.mark.parametrize("which", RIGS)
def test_deformation_matches_cpu_reference(request, which):
    rig = request.getfixturevalue(which)
    view = framing_pose(rig, yaw=10.0, pitch=5.0)
    rng, eye_rng = np.random.default_rng(0), np.random.default_rng(1)
    tol = 1e-4 * rig.face_size()
    from capture2face.render.skinning import Deformer
    from capture2face.rig.deform import deform

    deformer = Deformer(rig)
    with Renderer.create_from_options(rig, RenderOptions(size=64, wrinkles="off")) as renderer:
        for _ in range(3):
            bones = rig.bone_rest + rng.normal(0, 0.8, rig.bone_rest.shape) * (np.arange(rig.n_bones) > 0)[:, None]
            weights = rng.uniform(0, 1, rig.n_morphs)
            weights[rng.integers(rig.n_morphs)] = 0.0  # an inactive morph is skipped
            eyes = eye_rng.uniform(-30, 30, (2, 2))
            drawn = renderer.deformed_positions(FrameState(bones, weights, view, eye_rotation=eyes))
            cpu = cpu_deform(rig, bones, weights, eyes)
            assert np.abs(cpu - rig.vertices).max() > 0.3  # the deformation is not trivial
            assert np.abs(drawn - cpu).max() < tol
            # and the rig package's own reference agrees, normals included
            positions, normals = deformer(bones, weights, eye_rotation=eyes)
            ref_positions, ref_normals = deform(rig, bones, weights, eyes)
            assert np.abs(positions - ref_positions).max() < tol
            assert np.abs(normals - ref_normals).max() < 1e-5
            assert np.abs(normals - rig.normals).max() > 0.05  # the morphs bend them
    # Per-vertex blend of per-bone values: one-hot bones give back the skin weights.
    dense = rig.dense_skin_weights()
    assert np.abs(deformer.skin(np.eye(rig.n_bones)) - dense).max() < 1e-6


# ---------------------------------------------------------------------------------------
# Normal blending, NumPy and GLSL


def test_partial_derivative_round_trip():
    from capture2face.render.glsl_eval import eval_glsl

    n = random_unit_normals(200, 1)
    assert np.abs(pd_decode(pd_encode(n)) - n).max() < 1e-12
    glsl = eval_glsl("normal_blend.glsl", "pd_decode(pd_encode(a))", {"a": n}, 3)
    assert np.abs(glsl - n).max() < 1e-5
    # Blending is a weighted sum of derivatives: a flat map (derivative 0) adds nothing,
    # and two tilts add up.
    assert np.allclose(pd_encode(n) + pd_encode([0, 0, 1]), pd_encode(n))
    glsl_sum = eval_glsl("normal_blend.glsl", "pd_encode(a) + 0.5 * pd_encode(b)", {"a": n, "b": n[::-1]}, 2)
    assert np.abs(glsl_sum - (pd_encode(n) + 0.5 * pd_encode(n[::-1]))).max() < 1e-4


def test_oat_blend_with_flat_wrinkle_returns_base():
    from capture2face.render.glsl_eval import eval_glsl

    n = random_unit_normals(200, 2)
    flat = np.tile([0.0, 0.0, 1.0], (len(n), 1))
    assert np.abs(oat_blend(flat, n) - n).max() < 1e-12
    glsl = eval_glsl("normal_blend.glsl", "oat_blend(w, n)", {"w": flat, "n": n}, 3)
    assert np.abs(glsl - n).max() < 1e-5
    # A non-flat wrinkle does tilt the result, towards the wrinkle's direction.
    tilted = oat_blend(np.tile([0.6, 0.0, 0.8], (len(n), 1)), n)
    assert (tilted[:, 0] > n[:, 0]).all()


def test_srgb_encoding_within_a_quarter_level():
    from capture2face.render.glsl_eval import eval_glsl

    c = np.linspace(0.0, 1.0, 4001)[:, None].repeat(3, 1)
    exact = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    glsl = eval_glsl("color.glsl", "linear_to_srgb(a)", {"a": c}, 3)
    assert np.abs(glsl - exact).max() < 0.3 / 255
    assert (np.diff(glsl[:, 0]) >= 0).all()  # monotone


# ---------------------------------------------------------------------------------------
# Dynamic (area-change) driver


def test_dynamic_weights_compress_stretch_and_seam(rig):
    skin = rig.material == 0
    centre = rig.vertices[skin].mean(0)
    for scale, sign in ((0.8, 1.0), (1.25, -1.0)):
        scaled = centre + scale * (rig.vertices - centre)
        w = dynamic_wrinkle_weights(rig, scaled)
        expected = 1.0 - scale**2  # area ratio of a uniform scale
        assert np.sign(expected) == sign
        assert np.abs(w - expected).max() < 1e-5
    # Brows up: the forehead stretches non-uniformly; the two copies of each seam vertex
    # still get one weight, which they would not if the seam were not merged.
    bones = rig.pose_bones[rig.pose_index("stretch")]
    moved = cpu_deform(rig, bones, np.zeros(rig.n_morphs))
    w = dynamic_wrinkle_weights(rig, moved)
    ids, counts = np.unique(rig.position_ids, return_counts=True)
    shared = np.isin(rig.position_ids, ids[counts == 2])
    assert shared.sum() >= 2 * 30
    order = np.argsort(rig.position_ids[shared], kind="stable")
    pairs = w[shared][order].reshape(-1, 2)
    assert np.abs(pairs).max() > 0.01
    assert (pairs[:, 0] == pairs[:, 1]).all()
    split = dynamic_wrinkle_weights(rig.replace(position_ids=np.arange(rig.n_vertices, dtype=np.int32)), moved)
    split_pairs = split[shared][order].reshape(-1, 2)
    assert np.abs(split_pairs[:, 0] - split_pairs[:, 1]).max() > 1e-3
    assert w[rig.material == 0].min() < -0.05  # stretched somewhere


# ---------------------------------------------------------------------------------------
# Rendering


@pytest.fixture(scope="session", params=RIGS)
def rendered(request):
    """(rig, head pose, renders) at the stretch pose and rest, per driver/blend; shared."""
    rig = request.getfixturevalue(request.param)
    view = framing_pose(rig, yaw=10.0, pitch=5.0)
    stretch = FrameState.at_pose(rig, view, "stretch")
    zero = FrameState(stretch.bone_positions, stretch.blend_weights, view,
                      influences=np.zeros((len(rig.pose_names), rig.n_bones), np.float32))
    out = {}
    for driver, blend in (("off", "pd"), ("auto", "pd"), ("auto", "oat")):
        with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles=driver, normal_blend=blend)) as r:
            out[driver, blend, "stretch"] = r.render(stretch)
            out[driver, blend, "stretch again"] = r.render(stretch)
            out[driver, blend, "zero influence"] = r.render(zero)
            out[driver, blend, "rest"] = r.render(FrameState.at_pose(rig, view))
    return rig, view, out


def test_same_frame_twice_is_identical(rendered):
    _, _, renders = rendered
    for driver, blend in (("off", "pd"), ("auto", "pd"), ("auto", "oat")):
        a, b = renders[driver, blend, "stretch"], renders[driver, blend, "stretch again"]
        assert a.shape == (SIZE, SIZE, 3) and a.dtype == np.uint8
        assert a.std() > 10  # a face, not an empty frame
        assert np.array_equal(a, b)


@pytest.mark.parametrize("blend", ["pd", "oat"])
def test_auto_with_zero_influence_equals_off(rendered, blend):
    _, _, renders = rendered
    assert np.array_equal(renders["auto", blend, "zero influence"], renders["off", "pd", "stretch"])
    assert np.array_equal(renders["auto", blend, "rest"], renders["off", "pd", "rest"])


@pytest.mark.parametrize("blend", ["pd", "oat"])
def test_stretch_wrinkles_inside_forehead_only(rendered, blend):
    from capture2face.rig.influences import rig_influences, vertex_influences

    rig, view, renders = rendered
    stretch = rig.pose_index("stretch")
    bones = rig.pose_bones[stretch]
    moved = np.flatnonzero(np.linalg.norm(bones - rig.bone_rest, axis=1) > 0)
    diff = np.abs(renders["auto", blend, "stretch"].astype(int) - renders["off", "pd", "stretch"]).sum(2)
    outside = ~skinned_mask(rig, bones, view, SIZE, moved)
    assert outside.sum() > 0.5 * SIZE**2
    assert diff[outside].max() == 0
    # Inside: the forehead pixels most influenced by the stretch pose.
    influence = vertex_influences(rig_influences(bones[None], rig), rig.dense_skin_weights())[0, stretch]
    forehead = rig.region_weights[rig.region_names.index("forehead")] > 0.5
    core = (influence > 0.3) & forehead & (rig.material == 0)
    assert core.sum() >= 5
    pix = project(cpu_deform(rig, bones, np.zeros(rig.n_morphs))[core], view, 30.0, SIZE)
    inside = np.zeros_like(outside)
    x, y = np.floor(pix).astype(int).T
    for dy in range(-2, 3):  # a 5 x 5 neighbourhood of each core vertex
        for dx in range(-2, 3):
            inside[np.clip(y + dy, 0, SIZE - 1), np.clip(x + dx, 0, SIZE - 1)] = True
    # The default avatar's forehead furrows change ~84% of these pixels at 256 px (up to
    # ~135 levels summed over RGB); the test patch's ridges change almost all of them.
    assert (diff[inside] > 0).mean() > 0.6 and diff[inside].max() >= 30


# ---------------------------------------------------------------------------------------
# The default avatar's automatic wrinkles read clearly, and fade with the influence.

LOOK_SIZE = 512


def _luma(img: np.ndarray) -> np.ndarray:
    return img.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def _region_on_screen(rig, region, pose_name, view, size) -> np.ndarray:
    """(H, W) bool: convex hull of the region's core vertices (weight > 0.5), deformed to
    the reference pose and projected."""
    import cv2

    k = rig.pose_index(pose_name)
    core = rig.region_weights[rig.region_names.index(region)] > 0.5
    pix = project(cpu_deform(rig, rig.pose_bones[k], rig.pose_morph_weights[k])[core], view, 30.0, size)
    mask = np.zeros((size, size), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(pix).astype(np.int32)), 1)
    return mask.astype(bool)


@pytest.fixture(scope="session")
def avatar_looks(avatar):
    """Frontal default-avatar renders at 512 px: {(driver, pose): image}, and the view."""
    view = framing_pose(avatar, 0.0, 0.0, 0.0, 30.0)
    out = {}
    for driver in ("off", "auto"):
        with Renderer.create_from_options(avatar, RenderOptions(size=LOOK_SIZE, wrinkles=driver)) as r:
            for pose in ("stretch", "compress"):
                out[driver, pose] = r.render(FrameState.at_pose(avatar, view, pose))
    return view, out


# Mean |luminance(auto) - luminance(off)| (0-255 levels) inside the area at its pose.
# Measured: forehead 1.06 -> 12.0 and glabella 4.75 -> 13.4 after the forehead and the
# glabella were skinned to the brows, the furrows broadened and the key light made raking.
@pytest.mark.parametrize("pose, region, at_least", [("stretch", "forehead", 6.0), ("compress", "glabella", 8.0)])
def test_avatar_wrinkles_read_clearly(avatar, avatar_looks, pose, region, at_least):
    view, looks = avatar_looks
    area = _region_on_screen(avatar, region, pose, view, LOOK_SIZE)
    assert area.sum() > 300
    change = np.abs(_luma(looks["auto", pose]) - _luma(looks["off", pose]))
    assert change[area].mean() >= at_least
    # The lines are strong somewhere, not a faint overall tint.
    assert np.percentile(change[area], 95) >= 4 * at_least


def test_avatar_wrinkles_fade_in_with_the_influence(avatar, avatar_looks):
    """Scaling the stretch influence from 0 to 1 raises the forehead's change steadily:
    no popping (no step much larger than the average one), nothing before 0."""
    from capture2face.rig.influences import rig_influences

    view, looks = avatar_looks
    k = avatar.pose_index("stretch")
    full = rig_influences(avatar.pose_bones[k][None], avatar)[0]
    area = _region_on_screen(avatar, "forehead", "stretch", view, LOOK_SIZE)
    off = _luma(looks["off", "stretch"])[area]
    change = []
    with Renderer.create_from_options(avatar, RenderOptions(size=LOOK_SIZE, wrinkles="auto")) as r:
        for t in np.linspace(0.0, 1.0, 6):
            state = FrameState.at_pose(avatar, view, "stretch")
            state.influences = (t * full).astype(np.float32)
            change.append(np.abs(_luma(r.render(state))[area] - off).mean())
    steps = np.diff(change)
    assert change[0] == 0.0
    assert np.all(steps > 0)
    assert steps.max() < 1.6 * steps.mean()
    assert abs(change[-1] - np.abs(_luma(looks["auto", "stretch"])[area] - off).mean()) < 1e-9


def test_avatar_fills_the_frame(avatar, avatar_looks):
    """framing_pose makes the rendered face about 60% of the frame tall, centred; the rest
    of the head (scalp, ears, neck) goes on around it."""
    from capture2face.camera import project

    view, looks = avatar_looks
    img = looks["off", "compress"].astype(int)
    drawn = np.abs(img - img[0, 0]).sum(2) > 30
    face_px = project(avatar.vertices[avatar.material == 0], view, 30.0, LOOK_SIZE)
    rows, cols = face_px[:, 1], face_px[:, 0]
    assert 0.57 < (rows.max() - rows.min()) / LOOK_SIZE < 0.67
    assert abs((cols.max() + cols.min()) / 2 - LOOK_SIZE / 2) < 0.02 * LOOK_SIZE
    # The face's silhouette is drawn, and the head beyond it: scalp above, neck below.
    inside = face_px[(face_px >= 0).all(1) & (face_px < LOOK_SIZE).all(1)].astype(int)
    assert drawn[inside[:, 1], inside[:, 0]].mean() > 0.98
    hit = np.flatnonzero(drawn.any(1))
    assert hit.min() < rows.min() - 0.04 * LOOK_SIZE and hit.max() > rows.max() + 0.1 * LOOK_SIZE


def test_zones_driver_follows_zone_weights(rig, view):
    rest = FrameState.at_pose(rig, view)
    with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles="zones")) as r:
        none = r.render(rest)  # zone weights from blend weights: all zero at rest
        left = r.render(FrameState(rest.bone_positions, rest.blend_weights, view,
                                   zone_weights=np.array([-1, 0, 0, 0, 0, 0, 0, 0], np.float32)))
    with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles="off")) as r:
        off = r.render(rest)
    assert np.array_equal(none, off)
    diff = np.abs(left.astype(int) - off).sum(2)
    # Zone 0 is the top-left block of the UV square: u < 0.5 (x < 0, the image's left),
    # v < 1/3 (the top of the patch).
    ys, xs = np.nonzero(diff > 6)
    assert len(xs) > 100
    top = project(rig.vertices[rig.vertices[:, 1] > 8.5], view, 30.0, SIZE)
    centre = project(np.array([[0.0, 3.0, 5.0]]), view, 30.0, SIZE)[0]
    assert xs.max() < centre[0] + 3 and ys.max() < centre[1] + 3 and ys.min() > top[:, 1].min() - 3


def test_dynamic_driver_and_influence_view_render(rig, view):
    """Stretch raises the brow bones (1, 2) and leaves the jaw bone (3) at rest: the dynamic
    driver and the influence view change the skin the brows skin, and nothing the jaw
    alone skins."""
    stretch = FrameState.at_pose(rig, view, "stretch")
    images = {}
    for driver, mode in (("dynamic", "shaded"), ("off", "shaded"), ("auto", "influence"), ("off", "influence")):
        with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles=driver, view=mode)) as r:
            images[driver, mode] = r.render(stretch)
    brows = skinned_mask(rig, stretch.bone_positions, view, SIZE, [1, 2])
    jaw_only = skinned_mask(rig, stretch.bone_positions, view, SIZE, [3], dilate=0) & ~skinned_mask(
        rig, stretch.bone_positions, view, SIZE, [1, 2], dilate=6)
    assert brows.sum() > 2000 and jaw_only.sum() > 1000
    centres = np.round(project(stretch.bone_positions[1:3].astype(np.float64), view, 30.0, SIZE)).astype(int)

    dyn = np.abs(images["dynamic", "shaded"].astype(int) - images["off", "shaded"]).sum(2)
    assert (dyn > 4).sum() > 100 and dyn.max() > 10
    assert (dyn > 4)[brows].sum() >= 0.97 * (dyn > 4).sum()  # where the mesh stretched
    assert dyn[jaw_only].max() <= 4
    # Influence view: the stretch pose paints the skin the brows skin in the stretch colour
    # (blue), most strongly at the brow bones themselves; no influence: grey.
    infl = images["auto", "influence"].astype(int)
    grey = images["off", "influence"].astype(int)
    bluer = (infl[..., 2] - infl[..., 0]) - (grey[..., 2] - grey[..., 0])
    assert (bluer > 60).sum() > 200
    assert (bluer > 20)[~brows].sum() == 0  # nothing beyond the brows' skin
    for x, y in centres:
        assert bluer[y - 2:y + 3, x - 2:x + 3].min() > 100, (x, y)
    assert np.abs(bluer[jaw_only]).max() <= 2
    assert np.abs(grey[..., 0] - grey[..., 2]).max() < 30


def test_wrinkle_pd_layers_pack_two_maps_per_layer():
    """Wrinkle maps reach the shader as partial derivatives, maps 2j, 2j+1 in one RGBA
    layer; decoding them gives back the unit normals (to float16 precision)."""
    from capture2face.render.normal_blend import unpack_normal, wrinkle_pd_layers

    maps = np.stack([_ridges(32, 1, 3), _ridges(32, 0, 5), _ridges(32, 0, 2)])
    layers = wrinkle_pd_layers(maps)
    assert layers.shape == (2, 32, 32, 4) and layers.dtype == np.float16
    for k in range(3):
        d = layers[k // 2, ..., 2 * (k % 2):2 * (k % 2) + 2].astype(np.float64)
        assert np.abs(pd_decode(d) - unpack_normal(maps[k])).max() < 2e-3
        assert np.abs(d).max() > 0.5  # the ridges are there, not a flat map
    assert not layers[1, ..., 2:].any()  # no fourth map: flat


@pytest.mark.parametrize("driver", ["auto", "off"])
def test_influence_output_equals_the_influence_view(rig, view, driver):
    """One draw, two attachments: the shaded image is the plain render, the second one the
    influence view (the auto weights when the shading has no wrinkles)."""
    stretch = FrameState.at_pose(rig, view, "stretch")
    with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles=driver, influence_output=True)) as r:
        image, influence = r.render_with_influence(stretch)
        again = r.render(stretch)
    with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles=driver)) as r:
        plain = r.render(stretch)
        with pytest.raises(ValueError):
            r.render_with_influence(stretch)
    with Renderer.create_from_options(rig, RenderOptions(size=SIZE, wrinkles="auto", view="influence")) as r:
        separate = r.render(stretch)
    assert np.array_equal(image, plain) and np.array_equal(again, plain)
    assert np.array_equal(influence, separate)
    blue = influence[..., 2].astype(int) - influence[..., 0]
    assert (blue > 60).sum() > 200  # the stretch pose's forehead in the stretch colour


def test_fxaa_smooths_edges_like_msaa(avatar):
    """1 sample + FXAA: the silhouette's staircase is smoothed (closer to 4x MSAA than the
    plain single-sample image), the flat background and the face's interior are left
    alone, and the scissor box loses nothing."""
    view = framing_pose(avatar, yaw=25.0, pitch=8.0, roll=7.0)
    state = FrameState.at_pose(avatar, view, "compress")
    images = {}
    for name, kw in {"msaa": {"samples": 4}, "one": {"samples": 1}, "fxaa": {"samples": 1, "fxaa": True}}.items():
        with Renderer.create_from_options(avatar, RenderOptions(size=SIZE, wrinkles="auto", **kw)) as r:
            images[name] = r.render(state).astype(int)
            if name == "fxaa":
                box = r._screen_box(state)
                r._screen_box = lambda s: None  # the whole frame
                assert np.array_equal(r.render(state), images[name])
    assert box is not None and box[2] * box[3] < 0.9 * SIZE**2
    one, fxaa, msaa = images["one"], images["fxaa"], images["msaa"]
    changed = np.abs(fxaa - one).sum(2) > 0
    edges = np.abs(msaa - one).sum(2) > 30  # where MSAA differs: edges
    assert 200 < changed.sum() < 0.1 * SIZE**2
    assert np.abs(fxaa - msaa)[edges].mean() < 0.75 * np.abs(one - msaa)[edges].mean()
    assert np.array_equal(fxaa[:4], one[:4])  # background rows untouched


# ---------------------------------------------------------------------------------------
# Camera


def test_project_agrees_with_rasterizer(rig):
    """A dark dot painted in the albedo around one vertex's UV lands where ``project``
    puts that vertex (non-square frame, off-centre vertex, rotated head)."""
    tex = 512
    v = int(np.argmin(np.linalg.norm(rig.vertices - [-4.2, 5.1, 4.0], axis=1)))
    plain = np.full((tex, tex, 3), 230, np.uint8)
    albedo = plain.copy()
    cu, cv = rig.uvs[v] * tex
    yy, xx = np.mgrid[0:tex, 0:tex] + 0.5
    albedo[(xx - cu) ** 2 + (yy - cv) ** 2 < 12.0**2] = 0
    flat = np.full((tex, tex, 3), [128, 128, 255], np.uint8)
    size = (320, 240)
    pose = framing_pose(rig, yaw=-12.0, pitch=8.0, roll=5.0)
    state = FrameState.at_pose(rig, pose)
    images = []
    for image in (plain, albedo):
        with Renderer.create_from_options(rig.replace(albedo=image, normal_map=flat),
                                          RenderOptions(size=size, wrinkles="off", samples=1)) as r:
            images.append(r.render(state).astype(float).mean(2))
    darkness = np.clip(images[0] - images[1], 0, None)
    assert darkness.max() > 50
    ys, xs = np.mgrid[0:240, 0:320] + 0.5  # pixel centres
    centroid = np.array([(darkness * xs).sum(), (darkness * ys).sum()]) / darkness.sum()
    expected = project(rig.vertices[v:v + 1], pose, 30.0, size)[0]
    assert np.linalg.norm(centroid - expected) < 0.5
    # The dot is a few pixels wide, so that is well within it.
    assert 2 < np.sqrt((darkness > 25).sum() / np.pi) < 10


def test_framing_pose_centres_the_face(rig):
    for size in (256, (320, 240)):
        pose = framing_pose(rig, yaw=0.0)
        pix = project(rig.vertices[rig.material == 0], pose, 30.0, size)
        w, h = (size, size) if isinstance(size, int) else size
        fill = (pix[:, 1].max() - pix[:, 1].min()) / h
        assert 0.58 < fill < 0.7
        assert abs((pix[:, 0].max() + pix[:, 0].min()) / 2 - w / 2) < 0.02 * w


def test_heatmap_endpoints_and_shape():
    img = heatmap(np.linspace(0, 1, 11)[None].repeat(3, 0))
    assert img.shape == (3, 11, 3) and img.dtype == np.uint8
    assert img[0, 0].sum() < 120 and img[0, 1, 2] > 2 * img[0, 1, 0]  # cold end dark, then blue
    assert img[0, -1, 0] > 100 and img[0, -1, 0] > img[0, -1, 2]  # hot end is red
    assert np.abs(np.diff(img[0].astype(int), axis=0)).sum(1).min() > 0  # every step changes colour


# ---------------------------------------------------------------------------------------
# Video


def test_video_writer_frames_and_rate(tmp_path):
    import av

    from capture2face.io.video_output import VideoWriter

    path = tmp_path / "out.mp4"
    n, size = 12, (64, 48)
    with VideoWriter(path, 29.97, size) as out:
        for i in range(n):
            out.write(np.full((48, 64, 3), 20 * i, np.uint8))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mp4"]
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.average_rate == Fraction(2997, 100)
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
    assert len(frames) == n
    assert frames[0].shape == (48, 64, 3)
    assert np.allclose([f.mean() for f in frames], [20 * i for i in range(n)], atol=3)


def test_video_writer_is_atomic(tmp_path):
    from capture2face.io.video_output import VideoWriter

    with pytest.raises(RuntimeError), VideoWriter(tmp_path / "broken.mp4", 25, (32, 32)) as out:
        out.write(np.zeros((32, 32, 3), np.uint8))
        raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_back_face_culling_changes_no_visible_surface_of_the_avatar(avatar):
    """The built-in head is closed and wound consistently, so culling its back faces
    (``FaceRig.double_sided`` False: half the triangles a software renderer rasterizes)
    draws what drawing both sides draws: exactly at rest and turned aside (the back of the
    head and an ear towards the camera); with the mouth open and the head pitched, all but
    a few pixels where a lip-corner sliver is seen edge-on from behind (24 of 65536
    measured; a hole in the mouth bag would be hundreds)."""
    assert avatar.double_sided is False
    both = avatar.replace(double_sided=True)
    weights = np.zeros(avatar.n_morphs, np.float32)
    weights[avatar.morph_index("jawOpen")] = 0.5
    weights[avatar.morph_index("mouthFunnel")] = 0.5
    bones = avatar.bone_rest.copy()
    bones[avatar.bone_index("jaw"), 1] -= 0.5
    exact = [FrameState.at_pose(avatar, framing_pose(avatar, 0.0, 0.0, 0.0, 30.0)),
             FrameState.at_pose(avatar, framing_pose(avatar, 70.0, 10.0, 0.0, 30.0))]
    open_mouth = [FrameState(bone_positions=bones, blend_weights=weights,
                             head_pose=framing_pose(avatar, yaw, pitch, 0.0, 30.0))
                  for yaw, pitch in ((0.0, 0.0), (0.0, -20.0), (20.0, 25.0))]
    opts = RenderOptions(size=256, wrinkles="auto")
    with Renderer.create_from_options(avatar, opts) as culled, Renderer.create_from_options(both, opts) as full:
        for state in exact:
            assert np.abs(culled.render(state).astype(int) - full.render(state).astype(int)).max() <= 1
        for state in open_mouth:
            diff = np.abs(culled.render(state).astype(int) - full.render(state).astype(int)).max(-1)
            assert (diff > 8).sum() <= 40


def test_face_skin_and_the_rest_drawn_apart_whatever_the_triangle_order(avatar):
    """A frame is two draws (the face skin with its maps, the rest without): every
    triangle is drawn once, by the program of its material, so shuffling a rig's
    triangles (materials interleaved, as a glTF character's may be) draws the same image,
    wrinkles and eyes included; and the eyes take no wrinkle weight in the influence view."""
    rng = np.random.default_rng(3)
    shuffled = avatar.replace(triangles=avatar.triangles[rng.permutation(len(avatar.triangles))])
    state = FrameState.at_pose(avatar, framing_pose(avatar, 20.0, 5.0, 0.0, 30.0), "stretch")
    opts = RenderOptions(size=256, wrinkles="auto", samples=1, influence_output=True)
    with Renderer.create_from_options(avatar, opts) as r, Renderer.create_from_options(shuffled, opts) as s:
        assert [count for _, _, count, _ in r._draws] == [3 * int((avatar.material[avatar.triangles[:, 2]] == 0).sum()),
                                                       3 * int((avatar.material[avatar.triangles[:, 2]] != 0).sum())]
        image, influence = r.render_with_influence(state)
        image_s, influence_s = s.render_with_influence(state)
    assert np.array_equal(image, image_s) and np.array_equal(influence, influence_s)
    # The stretch pose (eyes open) lights the influence view blue on the forehead, never
    # on the irises, which show the plain grey shading.
    irises = r.deformed_positions(state)[avatar.landmark_vertices[[468, 473]]]
    px = np.floor(project(irises, state.head_pose, 30.0, (256, 256))).astype(int)
    iris_colour = influence[px[:, 1], px[:, 0]].astype(int)
    blue = influence[..., 2].astype(int) - influence[..., 0] > 60
    assert blue.sum() > 200 and np.ptp(iris_colour, axis=1).max() <= 2

"""The default avatar, its maps, and the CPU reference deformation."""

from __future__ import annotations

import numpy as np
import pytest

from capture2face.rig import maps as maps_mod
from capture2face.rig import mesh_ops
from capture2face.rig.avatar import (
    BONES,
    LIP_LOWER_LINES,
    LIP_PAIRS,
    LIP_UPPER_LINES,
    default_avatar,
    forget_built,
)
from capture2face.rig.avatar import parts as avatar_parts
from capture2face.rig.canonical import load_canonical_mesh
from capture2face.rig.deform import deform
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES, FaceRig
from capture2face.rig.influences import rig_influences

REQUIRED_MORPHS = ["jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight",
                   "mouthFunnel", "mouthPucker", "browInnerUp", "browDownLeft", "browDownRight", "cheekPuff"]


@pytest.fixture(scope="session")
def canon():
    return load_canonical_mesh()


def _zero_weights(rig):
    return np.zeros(rig.n_morphs, np.float32)


# ---- canonical mesh -------------------------------------------------------------------


def test_canonical_mesh_decodes(canon):
    assert canon.vertices.shape == (468, 3) and canon.uvs.shape == (468, 2)
    assert canon.triangles.shape == (898, 3) and canon.triangles.max() == 467
    v = canon.vertices
    assert v[263, 0] > 4 and v[33, 0] < -4  # +x is the subject's left
    assert v[10, 1] > 7 and v[152, 1] < -8  # +y up, cm
    assert v[1, 2] > 7  # the nose tip points +z
    assert canon.uvs[10, 1] < 0.12 and canon.uvs[152, 1] > 0.9  # UV origin top-left
    assert len(canon.procrustes_ids) > 10 and np.all(canon.procrustes_weights > 0)


# ---- geometry -------------------------------------------------------------------------


def test_geometry(avatar, canon):
    skin_tris = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    assert len(skin_tris) >= 3000
    np.testing.assert_array_equal(avatar.landmark_vertices[:468], np.arange(468))
    # The canonical vertices, except the lips, which are closed at rest.
    lips = np.isin(np.arange(468), LIP_UPPER_LINES + LIP_LOWER_LINES)
    np.testing.assert_allclose(avatar.vertices[:468][~lips], canon.vertices[~lips], atol=1e-6)
    for upper, lower in LIP_PAIRS:
        assert np.linalg.norm(avatar.vertices[upper] - avatar.vertices[lower]) < 1e-5
    assert np.linalg.norm(canon.vertices[13] - canon.vertices[14]) > 0.4
    assert avatar.triangles.min() >= 0 and avatar.triangles.max() < avatar.n_vertices
    assert set(np.unique(avatar.material)) == {0, 1, 2, 3, 4}
    np.testing.assert_allclose(np.linalg.norm(avatar.normals, axis=1), 1.0, atol=1e-5)
    # Skin normals face the camera on the front of the face.
    front = (avatar.material == 0) & (np.abs(avatar.vertices[:, 0]) < 3)
    assert (avatar.normals[front, 2] > 0).mean() > 0.95


def test_tangent_frames(avatar):
    t, w, n = avatar.tangents[:, :3], avatar.tangents[:, 3], avatar.normals
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-5)
    assert np.abs((t * n).sum(1)).max() < 1e-4
    assert set(np.unique(w)) <= {-1.0, 1.0}
    skin = avatar.material == 0
    bitangent = w[:, None] * np.cross(n, t)
    front = skin & (np.abs(avatar.vertices[:, 0]) < 3)
    # Tangent along +u = +x on the face, bitangent along -v = up.
    # (The nose wings' UVs run partly along the depth, so a few tangents tilt away.)
    assert (t[front, 0] > 0.2).mean() > 0.95
    assert (bitangent[front, 1] > 0.2).mean() > 0.95


def test_eyes_cover_the_openings(avatar):
    eye = avatar.material == 1
    for side, centre_landmark, rim in (("R", 468, [159, 145, 33, 133]), ("L", 473, [386, 374, 263, 362])):
        iris_vertices = avatar.landmark_vertices[centre_landmark:centre_landmark + 5]
        assert np.all(iris_vertices >= 0) and np.all(eye[iris_vertices])
        # The eyeball this iris belongs to: vertices connected to its centre.
        ball = _component(avatar, iris_vertices[0])
        p = avatar.vertices[ball]
        centre = 0.5 * (p.max(0) + p.min(0))
        radius = np.linalg.norm(p - centre, axis=1).mean()
        # Every lid contour vertex is inside the front silhouette and in front of the ball,
        # open and with the lid closed.
        loops = mesh_ops.boundary_loops(avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)])
        contour = next(loop for loop in loops if rim[0] in loop)
        for name in (None, "eyeBlinkLeft" if side == "L" else "eyeBlinkRight"):
            w = _zero_weights(avatar)
            if name:
                w[avatar.morph_index(name)] = 1.0
            pos, _ = deform(avatar, avatar.bone_rest, w)
            q = pos[contour]
            d = np.linalg.norm(q[:, :2] - centre[:2], axis=1)
            assert d.max() < radius
            surface_z = centre[2] + np.sqrt(radius**2 - d**2)
            assert (q[:, 2] - surface_z).min() > 0.0
        # The iris centre looks forward from the front pole.
        assert avatar.vertices[iris_vertices[0], 2] == pytest.approx(p[:, 2].max(), abs=1e-5)


def test_eyes_turn_about_their_centres_behind_the_lids(avatar):
    from capture2face.rig.face_rig import eye_rotation_matrices, gaze_angles, gaze_directions

    assert avatar.has_eyes and avatar.eye_centres.shape == (2, 3)
    for side, first in ((0, 468), (1, 473)):
        ball = avatar.eye_vertex_side == side
        assert np.all(avatar.material[ball] == 1) and ball.sum() > 100
        iris = avatar.landmark_vertices[first:first + 5]
        assert np.all(avatar.eye_vertex_side[iris] == side)
        # The centre is the sphere's: every eyeball vertex at one distance from it.
        r = np.linalg.norm(avatar.vertices[ball] - avatar.eye_centres[side], axis=1)
        assert r.std() < 1e-4 * r.mean()
    assert avatar.eye_centres[0, 0] < 0 < avatar.eye_centres[1, 0]  # right eye at -x
    # Yaw 30 (towards +x), pitch 20 (down) on both eyes: the iris centres move that way,
    # the eyeballs turn rigidly, nothing else moves, and the gaze reads back.
    turn = np.array([[30.0, 20.0], [30.0, 20.0]])
    pos, nrm = deform(avatar, avatar.bone_rest, _zero_weights(avatar), turn)
    rest, _ = deform(avatar, avatar.bone_rest, _zero_weights(avatar))
    moved = np.linalg.norm(pos - rest, axis=1) > 1e-6
    assert np.array_equal(moved, avatar.eye_vertex_side >= 0)
    for side, first in ((0, 468), (1, 473)):
        c = avatar.eye_centres[side]
        v = pos[avatar.landmark_vertices[first]] - c
        np.testing.assert_allclose(gaze_angles(v), [30.0, 20.0], atol=1e-3)
        assert v[0] > 0 and v[1] < 0
        ball = avatar.eye_vertex_side == side
        np.testing.assert_allclose(np.linalg.norm(pos[ball] - c, axis=1), np.linalg.norm(rest[ball] - c, axis=1),
                                   atol=1e-5)
        np.testing.assert_allclose(nrm[ball], avatar.normals[ball] @ eye_rotation_matrices(turn[side]).T, atol=1e-5)
    np.testing.assert_allclose(gaze_directions(np.zeros(2)), [0.0, 0.0, 1.0], atol=1e-12)


def test_rotation_conventions_shared_by_camera_and_eyes():
    """One rotation_ypr (no GL import) for the camera and the eyes: its axes, and the eyes'
    Ry(yaw) Rx(pitch) with the pitch tipping the gaze down."""
    from capture2face import camera
    from capture2face.maths.rotations import rotation_ypr
    from capture2face.rig.face_rig import eye_rotation_matrices

    assert camera.rotation_ypr is rotation_ypr  # the old import path still works
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(rotation_ypr(np.array([90.0, 0, 0])) @ z, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_ypr(np.array([0, 90.0, 0])) @ z, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_ypr(np.array([0, 0, 90.0])) @ x, [0, 1, 0], atol=1e-12)
    yaw, pitch = np.radians(25.0), np.radians(-40.0)
    ry = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    rx = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    np.testing.assert_allclose(eye_rotation_matrices(np.array([25.0, -40.0])), ry @ rx, atol=1e-12)
    assert (eye_rotation_matrices(np.array([0.0, 30.0])) @ z)[1] == pytest.approx(-0.5)  # pitch > 0: down
    turns = np.random.default_rng(1).uniform(-60, 60, (7, 2, 2))
    assert eye_rotation_matrices(turns).shape == (7, 2, 3, 3)


def test_avatar_mesh_helpers_make_closed_outward_spheres_and_grids():
    """The sphere triangulation shared by the eyeballs, the tongue and the ears is closed
    (every edge once each way), in either order; the grid has 2 triangles per quad; and
    _face_outwards turns an inward sphere out."""
    tris = avatar_parts._sphere_triangles(5, 8)
    rings = avatar_parts._sphere_triangles(5, 8, ring_by_ring=True)
    assert len(tris) == 2 * 8 + 2 * 8 * 4 and tris.dtype == np.int32
    assert sorted(map(tuple, tris)) == sorted(map(tuple, rings))
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    assert len({tuple(e) for e in edges}) == len(edges)  # each directed edge once
    assert {tuple(e) for e in edges} == {tuple(e) for e in edges[:, ::-1]}  # and its reverse
    dirs, _, _, sphere = avatar_parts._uv_sphere(6, 10)
    out = avatar_parts._face_outwards(dirs, sphere, np.zeros(3))
    inward = avatar_parts._face_outwards(dirs, out[:, ::-1], np.zeros(3))
    assert np.array_equal(inward, out)
    p = dirs[out]
    assert (np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p.mean(1)) > 0).all()
    grid = avatar_parts._grid_triangles_by_half(4, 5)
    assert grid.shape == (2 * 3 * 4, 3) and grid.max() == 19
    assert avatar_parts._grid_triangles(4, 5, closed=True).shape == (3, 5, 2, 3)


def _component(rig, vertex):
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    edges, _ = mesh_ops.unique_edges(rig.triangles)
    g = sp.coo_matrix((np.ones(len(edges)), tuple(edges.T)), shape=(rig.n_vertices,) * 2)
    _, labels = connected_components(g, directed=False)
    return np.flatnonzero(labels == labels[vertex])


def test_mouth_interior_behind_the_lips(avatar):
    mouth = avatar.material == 2
    assert mouth.sum() > 40
    lips = avatar.vertices[[13, 14, 78, 308]]
    assert avatar.vertices[mouth, 2].max() <= lips[:, 2].max() + 1e-6
    # The bag is drawn from both sides (back faces are culled and an opening jaw turns some
    # walls away): every triangle twice, once in each winding.
    tris = avatar.triangles[mouth[avatar.triangles].all(1)]
    half = len(tris) // 2
    assert len(tris) == 2 * half
    np.testing.assert_array_equal(tris[half:], tris[:half, ::-1])
    # The first copy faces forward-ish (towards the camera through the opening).
    p = avatar.vertices[tris[:half]]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (n[:, 2] > -1e-9).mean() > 0.5


def test_teeth_and_tongue(avatar):
    from scipy.spatial import cKDTree

    parts = avatar.material == 3
    assert parts.sum() > 300
    head, jaw = 0, avatar.bone_index("jaw")
    joints = avatar.skin_joints[parts, 0]
    assert np.all(avatar.skin_weights[parts, 0] == 1.0) and set(joints.tolist()) == {head, jaw}
    upper = np.flatnonzero(parts)[joints == head]
    lower = np.flatnonzero(parts)[joints == jaw]  # lower teeth and tongue
    lip_y = avatar.vertices[13, 1]
    assert avatar.vertices[upper, 1].min() < lip_y < avatar.vertices[upper, 1].max()  # upper edge below the lip line
    assert avatar.vertices[lower, 1].max() < lip_y
    # Behind the lips: every skin vertex over a tooth (within 0.3 cm seen from the front)
    # is in front of it, so a closed mouth hides the teeth.
    skin = np.flatnonzero(avatar.material == 0)
    tree = cKDTree(avatar.vertices[skin, :2])
    for v in np.flatnonzero(parts):
        near = tree.query_ball_point(avatar.vertices[v, :2], 0.3)
        assert near and avatar.vertices[skin[near], 2].min() > avatar.vertices[v, 2]
    # The jaw opens the lower teeth and the tongue with the lower lip; the upper teeth stay.
    w = _zero_weights(avatar)
    w[avatar.morph_index("jawOpen")] = 1.0
    bones = avatar.bone_rest.copy()
    bones[jaw] += [0.0, -0.5, 0.0]
    pos, _ = deform(avatar, bones, w)
    assert np.abs(pos[upper] - avatar.vertices[upper]).max() < 1e-6
    drop = avatar.vertices[lower, 1] - pos[lower, 1]
    assert drop.min() > 0.5 and avatar.vertices[14, 1] - pos[14, 1] > 0.5
    # The lower teeth move as one piece (a rigid jaw turn plus the bone's shift).
    d = np.linalg.norm(pos[lower][:, None] - pos[lower][None, ::50], axis=-1)
    d0 = np.linalg.norm(avatar.vertices[lower][:, None] - avatar.vertices[lower][None, ::50], axis=-1)
    assert np.abs(d - d0).max() < 1e-4


def test_head_is_joined_to_the_face_without_a_crack(avatar):
    head = avatar.material == 4
    assert head.sum() > 1000
    # The face keeps its canonical vertices; the head only adds.
    assert np.all(avatar.landmark_vertices[:468] == np.arange(468)) and np.all(avatar.material[:468] == 0)
    # Face and head are one closed surface once copies of a position are welded: its only
    # borders are the eye openings and the mouth.
    shell = avatar.triangles[np.isin(avatar.material[avatar.triangles], (0, 4)).all(1)]
    loops = mesh_ops.boundary_loops(avatar.position_ids[shell])
    assert len(loops) == 3
    assert sorted(len(set(loop) & {33, 263, 13}) for loop in loops) == [1, 1, 1]
    shared = np.flatnonzero(avatar.position_ids != np.arange(avatar.n_vertices))
    assert np.all(head[shared]) and (avatar.material[avatar.position_ids[shared]] == 0).sum() > 50
    # Copies share their normal, and stay together under any bones and morphs (the head's
    # first ring follows the face's edge): no crack, no shading seam.
    rng = np.random.default_rng(0)
    bones = avatar.bone_rest + rng.normal(0, 0.5, avatar.bone_rest.shape) * (np.arange(avatar.n_bones) > 0)[:, None]
    w = rng.uniform(0, 1, avatar.n_morphs).astype(np.float32)
    for b, weights in ((avatar.bone_rest, _zero_weights(avatar)), (bones, w)):
        pos, nrm = deform(avatar, b, weights)
        assert np.abs(pos[shared] - pos[avatar.position_ids[shared]]).max() < 1e-5
        assert np.abs(nrm[shared] - nrm[avatar.position_ids[shared]]).max() < 1e-5
    # A head: the scalp over the forehead, ears at the sides, a neck under the chin.
    v = avatar.vertices
    assert v[head, 1].max() > v[avatar.material == 0, 1].max() + 2.0
    assert v[head, 2].min() < v[:, 2].max() - 18.0  # ~20 cm front to back
    assert v[head, 1].min() < v[152, 1] - 10.0
    for side in (-1, 1):
        ear = head & (side * v[:, 0] > np.abs(v[avatar.material == 0, 0]).max()) & (np.abs(v[:, 1] - v[33, 1]) < 4)
        assert ear.sum() > 50


def test_scalp_is_hair_and_the_neck_skin(avatar):
    head = np.flatnonzero(avatar.material == 4)
    texel = np.clip((avatar.uvs[head] * avatar.albedo.shape[0]).astype(int), 0, avatar.albedo.shape[0] - 1)
    colour = avatar.albedo[texel[:, 1], texel[:, 0]].astype(float)
    v = avatar.vertices[head]
    crown = v[:, 1] > v[:, 1].max() - 2.0
    neck = v[:, 1] < avatar.vertices[152, 1] - 3.0
    skin = avatar.albedo[_uv_texel(avatar, 234)].astype(float)  # the face's edge at the cheek
    assert colour[crown].mean() < 0.5 * skin.mean()  # dark hair
    assert np.abs(colour[neck].mean(0) - skin).max() < 25  # the face's skin tone


def _uv_texel(rig, vertex):
    t = np.clip((rig.uvs[vertex] * rig.albedo.shape[0]).astype(int), 0, rig.albedo.shape[0] - 1)
    return t[1], t[0]


def test_texture_layout_keeps_eyes_and_mouth_off_the_skin(avatar):
    skin_tris = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    covered = maps_mod._coverage(avatar.uvs, skin_tris, 1024)
    for material in (1, 2, 3, 4):
        uv = avatar.uvs[avatar.material == material]
        texels = np.clip((uv * 1024).astype(int), 0, 1023)
        assert not covered[texels[:, 1], texels[:, 0]].any()


# ---- bones and skinning ---------------------------------------------------------------


def test_bones(avatar):
    assert 21 <= avatar.n_bones <= 31
    assert avatar.bone_names[0] == "head" and avatar.bone_parents[0] == -1 and avatar.bone_landmarks[0] == -1
    assert np.all(avatar.bone_parents[1:] == 0)
    lm = avatar.bone_landmarks[1:]
    assert np.all((lm >= 0) & (lm < len(avatar.landmark_vertices)))
    assert np.all(avatar.landmark_vertices[lm] >= 0)
    np.testing.assert_array_equal(avatar.bone_rest[1:], avatar.vertices[avatar.landmark_vertices[lm]])
    assert len(set(avatar.bone_names)) == avatar.n_bones
    for part in ("brow_inner", "brow_mid", "brow_outer", "eyelid_upper", "eyelid_lower", "cheek", "cheek_upper",
                 "nose_wing", "lip_upper", "mouth_corner", "lip_lower"):
        assert f"{part}_L" in avatar.bone_names and f"{part}_R" in avatar.bone_names
    for side, sign in (("_L", 1), ("_R", -1)):
        xs = [avatar.bone_rest[i, 0] for i, n in enumerate(avatar.bone_names) if n.endswith(side)]
        assert np.all(np.sign(xs) == sign)
    # The brows of one side share a group; the lips do not.
    g = dict(zip(avatar.bone_names, avatar.bone_groups))
    assert g["brow_inner_L"] == g["brow_mid_L"] == g["brow_outer_L"] != g["brow_inner_R"]
    assert g["lip_upper_C"] != g["lip_lower_C"]


def test_skin_weights_convex(avatar):
    w, j = avatar.skin_weights, avatar.skin_joints
    assert w.shape == (avatar.n_vertices, 4) and j.shape == (avatar.n_vertices, 4)
    assert w.dtype == np.float32 and j.dtype == np.int32
    assert w.min() >= 0.0
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    assert j.min() >= 0 and j.max() < avatar.n_bones
    dense = avatar.dense_skin_weights()
    assert ((dense > 0).sum(1) <= 4).all()
    # Eyes ride the head bone only.
    assert np.all(dense[avatar.material == 1, 0] == 1.0)


def test_skin_weights_local_and_smooth(avatar):
    dense = avatar.dense_skin_weights()
    skin = np.flatnonzero(avatar.material == 0)
    for b, spec in enumerate(BONES[1:], start=1):
        # Geodesic distance >= Euclidean: beyond the support in space the weight must be 0.
        far = np.linalg.norm(avatar.vertices[skin] - avatar.bone_rest[b], axis=1) > spec.support
        assert far.any() and np.all(dense[skin[far], b] == 0.0), spec.name
        # The bone dominates its own landmark.
        own = avatar.landmark_vertices[spec.landmark]
        assert dense[own, b] >= 0.35 and dense[own, b] == dense[own].max(), spec.name
    # Smooth: the weights change by less than 2.5 per cm along any skin edge.
    edges, _ = mesh_ops.unique_edges(avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)])
    length = np.linalg.norm(avatar.vertices[edges[:, 0]] - avatar.vertices[edges[:, 1]], axis=1)
    slope = np.abs(dense[edges[:, 0]] - dense[edges[:, 1]]).max(1) / length
    assert slope.max() < 2.5
    # Upper and lower lips are separated: the lower-lip bone does not move the upper lip.
    assert dense[13, avatar.bone_index("lip_lower_C")] == 0.0
    assert dense[14, avatar.bone_index("lip_upper_C")] == 0.0
    assert dense[159, avatar.bone_index("eyelid_lower_R")] == 0.0


# ---- deformation ----------------------------------------------------------------------


def test_rest_pose_reproduces_rest_vertices(avatar):
    pos, nrm = deform(avatar, avatar.bone_rest, _zero_weights(avatar))
    np.testing.assert_array_equal(pos, avatar.vertices)
    np.testing.assert_allclose(nrm, avatar.normals, atol=1e-6)


def test_morph_at_weight_one_reproduces_target(avatar):
    for m, name in enumerate(avatar.morph_names):
        w = _zero_weights(avatar)
        w[m] = 1.0
        pos, nrm = deform(avatar, avatar.bone_rest, w)
        target = avatar.vertices.astype(np.float64) + avatar.morph_positions[m]
        np.testing.assert_allclose(pos, target, atol=1e-5, err_msg=name)
        # Normal deltas are the normals of the morphed mesh minus the rest normals (copies
        # of one position, at UV seams, share theirs).
        expected = mesh_ops.vertex_normals(target, avatar.position_ids[avatar.triangles])[avatar.position_ids]
        np.testing.assert_allclose(nrm, expected, atol=2e-4, err_msg=name)
        assert np.abs(avatar.morph_positions[m]).max() > 0.1, name  # it does something


def test_required_morphs(avatar):
    assert set(REQUIRED_MORPHS) <= set(avatar.morph_names)
    assert avatar.morph_positions.shape == avatar.morph_normals.shape == (avatar.n_morphs, avatar.n_vertices, 3)


def test_morphs_move_the_right_features(avatar):
    def moved(name):
        w = _zero_weights(avatar)
        w[avatar.morph_index(name)] = 1.0
        return deform(avatar, avatar.bone_rest, w)[0] - avatar.vertices

    jaw = moved("jawOpen")
    assert jaw[152, 1] < -1.0 and np.linalg.norm(jaw[152]) > 2.0  # the chin swings down and back
    assert jaw[14, 1] < -1.0 and jaw[152, 2] < 0  # and the lower lip drops
    assert np.abs(jaw[13]).max() < 0.05 and np.abs(jaw[10]).max() < 1e-6  # upper lip, forehead stay
    blink = moved("eyeBlinkLeft")
    closed = avatar.vertices + blink
    assert np.linalg.norm(closed[386] - closed[374]) < 0.2 < np.linalg.norm(avatar.vertices[386] - avatar.vertices[374])
    assert np.abs(blink[159]).max() < 1e-6  # the other eye stays open
    smile = moved("mouthSmileLeft")
    assert smile[291, 1] > 0.3 and smile[291, 0] > 0.3 and np.abs(smile[61]).max() < 0.05
    inner = moved("browInnerUp")
    assert inner[107, 1] > 0.5 and inner[336, 1] > 0.5
    down = moved("browDownLeft")
    assert down[334, 1] < -0.3 and down[336, 0] < -0.1  # down and towards the middle
    pucker = moved("mouthPucker")
    assert pucker[0, 2] > 0.3 and pucker[291, 0] < -0.4 and pucker[61, 0] > 0.4
    puff = moved("cheekPuff")
    assert (puff[[205, 425]] * avatar.normals[[205, 425]]).sum(1).min() > 0.2


def test_translation_only_skinning(avatar):
    b = avatar.bone_index("jaw")
    bones = avatar.bone_rest.copy()
    bones[b] += [0.0, -1.0, 0.5]
    pos, nrm = deform(avatar, bones, _zero_weights(avatar))
    dense = avatar.dense_skin_weights()
    np.testing.assert_allclose(pos - avatar.vertices, dense[:, b:b + 1] * np.array([0.0, -1.0, 0.5]), atol=1e-5)
    np.testing.assert_allclose(nrm, avatar.normals, atol=1e-6)  # translations do not rotate normals


def test_batched_deform_matches_single_frames(avatar):
    rng = np.random.default_rng(0)
    bones = avatar.bone_rest[None] + rng.normal(0, 0.3, (3, avatar.n_bones, 3)).astype(np.float32)
    weights = rng.uniform(0, 1, (3, avatar.n_morphs)).astype(np.float32)
    pos, nrm = deform(avatar, bones, weights)
    assert pos.shape == nrm.shape == (3, avatar.n_vertices, 3)
    for f in range(3):
        p1, n1 = deform(avatar, bones[f], weights[f])
        np.testing.assert_allclose(pos[f], p1, atol=1e-6)
        np.testing.assert_allclose(nrm[f], n1, atol=1e-6)
    with pytest.raises(ValueError):
        deform(avatar, bones, weights[0])


# ---- poses, regions, zones ------------------------------------------------------------


def test_reference_poses(avatar):
    assert avatar.pose_names == ["stretch", "compress"]
    assert [avatar.wrinkle_map_names[i] for i in avatar.pose_maps] == ["stretch", "compress"]
    travel = np.linalg.norm(avatar.pose_bones - avatar.bone_rest, axis=2)  # (P, B)
    assert np.all(travel[:, 0] == 0)
    assert travel[:, 1:].min() >= 0.2 and travel.max() <= 1.6
    s, c = avatar.pose_bones - avatar.bone_rest
    brows = [avatar.bone_index(n) for n in avatar.bone_names if n.startswith("brow")]
    assert np.all(s[brows, 1] > 0.5) and np.all(c[brows, 1] < -0.3)  # raised / lowered
    inner = avatar.bone_index("brow_inner_L"), avatar.bone_index("brow_inner_R")
    assert c[inner[0], 0] < 0 < c[inner[1], 0]  # together
    corners = avatar.bone_index("mouth_corner_L"), avatar.bone_index("mouth_corner_R")
    assert c[corners[0], 0] < -0.4 and c[corners[1], 0] > 0.4  # puckered
    assert s[avatar.bone_index("jaw"), 1] < -0.5  # mouth open


def test_pose_influences_are_one_at_each_pose_and_zero_at_rest(avatar):
    frames = np.concatenate([avatar.bone_rest[None], avatar.pose_bones])  # rest, stretch, compress
    inf = rig_influences(frames, avatar)  # (F, P, B)
    np.testing.assert_array_equal(inf[0], 0.0)
    for k in range(len(avatar.pose_names)):
        np.testing.assert_array_equal(inf[1 + k, k, 1:], 1.0)
        assert inf[1 + k, k, 0] == 0.0


def test_forehead_and_glabella_follow_the_brows(avatar):
    """Their skin is weighted to the brow bones (Dutreve bone masks), so at the reference
    poses their per-vertex wrinkle influence is close to 1; the hairline stays partly
    with the head."""
    from capture2face.rig.influences import vertex_influences

    dense = avatar.dense_skin_weights()
    for pose, region, at_least in (("stretch", "forehead", 0.88), ("compress", "glabella", 0.95)):
        k = avatar.pose_index(pose)
        inf = vertex_influences(rig_influences(avatar.pose_bones[k][None], avatar), dense)[0, k]
        core = avatar.region_weights[avatar.region_names.index(region)] > 0.5
        assert inf[core].mean() >= at_least, region
    skin_tris = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    outer = max(mesh_ops.boundary_loops(skin_tris), key=len)
    hairline = outer[avatar.vertices[outer, 1] > avatar.vertices[[105, 334], 1].max() + 1.0]
    assert len(hairline) >= 5 and dense[hairline, 0].min() >= 0.3


def test_regions(avatar):
    assert avatar.region_names == REGION_NAMES
    r = avatar.region_weights
    assert r.shape == (len(REGION_NAMES), avatar.n_vertices) and r.min() >= 0 and r.max() <= 1
    assert np.all(r[:, avatar.material != 0] == 0)
    centre = (r @ avatar.vertices) / r.sum(1, keepdims=True)
    c = dict(zip(REGION_NAMES, centre))
    brow_y = avatar.vertices[[105, 334], 1].mean()
    assert c["forehead"][1] > brow_y and abs(c["forehead"][0]) < 0.5
    assert c["glabella"][1] > avatar.vertices[168, 1] and abs(c["glabella"][0]) < 0.3
    assert c["crows_feet_left"][0] > avatar.vertices[263, 0] > 0 > avatar.vertices[33, 0] > c["crows_feet_right"][0]
    assert c["nasolabial_left"][0] > 0 > c["nasolabial_right"][0]
    assert c["chin"][1] < avatar.vertices[17, 1]
    assert (r > 0.5).sum(1).min() >= 10


def test_zones(avatar):
    assert avatar.zone_names == ZONE_NAMES
    assert avatar.zone_masks.shape == (1024, 1024, 8) and avatar.zone_masks.dtype == np.uint8
    assert (avatar.zone_masks == 255).reshape(-1, 8).sum(0).min() > 500
    t = dict(zip(avatar.morph_names, avatar.zone_table))
    z = ZONE_NAMES.index
    assert t["browInnerUp"][z("forehead_left")] < 0 and t["browInnerUp"][z("forehead_right")] < 0
    assert t["browDownLeft"][z("glabella")] > 0 and t["browDownRight"][z("glabella")] > 0
    assert t["eyeSquintLeft"][z("crows_feet_left")] > 0 and t["eyeSquintRight"][z("crows_feet_right")] > 0
    assert t["mouthSmileLeft"][z("nasolabial_left")] > 0 and t["mouthSmileLeft"][z("nasolabial_right")] == 0
    assert t["mouthPucker"][z("chin")] > 0 and t["jawOpen"][z("chin")] < 0  # these cancel


# ---- maps -----------------------------------------------------------------------------


def _gradient_energy(normal_map, mask):
    """Energy of the normal map's x (d/du) and y (d/dv) components under a mask."""
    n = maps_mod.decode_normals(normal_map)
    w = mask.astype(np.float64) / 255.0
    return (w * n[..., 0] ** 2).sum(), (w * n[..., 1] ** 2).sum()


def test_stretch_map_forehead_lines_are_horizontal(avatar):
    stretch = avatar.wrinkle_maps[avatar.wrinkle_map_names.index("stretch")]
    forehead = avatar.zone_masks[..., 0].astype(np.float64) + avatar.zone_masks[..., 1]
    across_u, across_v = _gradient_energy(stretch, np.clip(forehead, 0, 255))
    assert across_v > 8 * across_u  # horizontal lines: the height changes along v
    assert across_v / (forehead > 0).sum() > 1e-3  # and they are there


def test_compress_map_glabella_lines_are_vertical(avatar):
    compress = avatar.wrinkle_maps[avatar.wrinkle_map_names.index("compress")]
    across_u, across_v = _gradient_energy(compress, avatar.zone_masks[..., ZONE_NAMES.index("glabella")])
    assert across_u > 5 * across_v


def test_compress_map_has_all_its_wrinkles(avatar):
    compress = avatar.wrinkle_maps[avatar.wrinkle_map_names.index("compress")]
    stretch = avatar.wrinkle_maps[avatar.wrinkle_map_names.index("stretch")]
    for zone in ("crows_feet_left", "crows_feet_right", "nasolabial_left", "nasolabial_right", "chin"):
        mask = avatar.zone_masks[..., ZONE_NAMES.index(zone)]
        ex, ey = _gradient_energy(compress, mask)
        sx, sy = _gradient_energy(stretch, mask)
        assert ex + ey > 20 * (sx + sy) + 1e-3, zone  # wrinkled in compress, smooth in stretch


def test_base_normal_map_has_pores(avatar):
    n = maps_mod.decode_normals(avatar.normal_map)
    skin = (avatar.zone_masks.max(-1) > 0)
    tilt = np.degrees(np.arccos(np.clip(n[..., 2], -1, 1)))
    assert 0.5 < np.median(tilt[skin]) < 15  # fine detail, not flat and not wild
    # High-frequency: neighbouring texels differ (pore scale is a few texels).
    assert np.abs(np.diff(n[..., 0], axis=1))[skin[:, 1:]].mean() > 0.005


def test_albedo_reads_as_skin(avatar):
    a = avatar.albedo.astype(np.float64)
    cheek = a[int(0.6 * 1024), int(0.3 * 1024)]
    assert cheek[0] > cheek[1] > cheek[2] and 150 < cheek[0] < 250  # warm, light
    lip = a[int(avatar.uvs[0, 1] * 1024) + 6, int(avatar.uvs[0, 0] * 1024)]
    assert lip[0] - lip[1] > cheek[0] - cheek[1] + 20  # lips redder
    v0, u0 = (avatar.uvs[[105, 52]].mean(0)[::-1] * 1024).astype(int)
    brow = a[v0 - 3:v0 + 4, u0 - 10:u0 + 11].reshape(-1, 3).mean(0)
    assert brow.mean() < cheek.mean() - 40  # brows darker


def test_height_to_normal_convention():
    # A ramp rising along +u tilts normals towards -u (x < 0); rising along +v (down the
    # image) tilts them towards +y (the bitangent points along -v).
    ramp_u = np.tile(np.arange(16, dtype=float), (16, 1))
    n = maps_mod.height_to_normal(ramp_u)
    assert n[8, 8, 0] < -0.5 and abs(n[8, 8, 1]) < 1e-9
    n = maps_mod.height_to_normal(ramp_u.T)
    assert n[8, 8, 1] > 0.5 and abs(n[8, 8, 0]) < 1e-9
    flat = maps_mod.encode_normals(maps_mod.height_to_normal(np.zeros((4, 4))))
    assert tuple(flat[0, 0]) == (128, 128, 255)


def test_write_maps_cli(avatar, tmp_path):
    import cv2

    from capture2face.cli import main

    assert main(["avatar", "--maps", str(tmp_path)]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["albedo.png", "normal.png", "wrinkle_compress.png", "wrinkle_stretch.png",
                     "zones_0.png", "zones_1.png"]
    albedo = cv2.cvtColor(cv2.imread(str(tmp_path / "albedo.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(albedo, avatar.albedo)
    zones = cv2.imread(str(tmp_path / "zones_1.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(cv2.cvtColor(zones, cv2.COLOR_BGRA2RGBA), avatar.zone_masks[..., 4:])


# ---- persistence and variants ---------------------------------------------------------


def test_save_load_bit_exact(avatar, tmp_path):
    path = tmp_path / "a.rig.npz"
    avatar.save(path)
    back = FaceRig.load(path)
    for name, value in vars(avatar).items():
        other = getattr(back, name)
        if isinstance(value, np.ndarray):
            assert other.dtype == value.dtype and other.shape == value.shape, name
            np.testing.assert_array_equal(other, value, err_msg=name)
        else:
            assert other == value, name


def test_cache_is_reused(tmp_path, monkeypatch, avatar):
    monkeypatch.setenv("CAPTURE2FACE_CACHE", str(tmp_path))
    forget_built()
    try:
        first = default_avatar()
        files = list(tmp_path.glob("avatar-default-*.rig.npz"))
        assert len(files) == 1
        forget_built()
        again = default_avatar()  # from the file this time
        np.testing.assert_array_equal(again.morph_positions, first.morph_positions)
        np.testing.assert_array_equal(first.vertices, avatar.vertices)
    finally:
        forget_built()


def test_wide_variant(avatar, wide):
    assert wide.name != avatar.name
    np.testing.assert_array_equal(wide.triangles, avatar.triangles)
    assert wide.bone_names == avatar.bone_names and wide.morph_names == avatar.morph_names
    assert wide.interocular() == pytest.approx(1.15 * avatar.interocular(), rel=0.02)
    lift = wide.vertices[[105, 334], 1] - avatar.vertices[[105, 334], 1]
    assert np.all((lift > 0.35) & (lift < 0.65))
    np.testing.assert_array_equal(wide.landmark_vertices, avatar.landmark_vertices)


def test_unknown_variant_is_a_user_error():
    from capture2face.errors import CaptureError

    with pytest.raises(CaptureError):
        default_avatar("nonexistent")


def test_iris_landmarks_follow_mediapipe_order(avatar):
    # MediaPipe (checked on a real clip): 468/473 iris centres of the subject's right/left
    # eye, then rim points towards the subject's left (+x), up, right, down.
    for centre in (468, 473):
        c, *rim = avatar.vertices[avatar.landmark_vertices[centre:centre + 5]]
        d = np.array(rim) - c
        assert d[0, 0] > 0.3 and d[1, 1] > 0.3 and d[2, 0] < -0.3 and d[3, 1] < -0.3
    assert avatar.vertices[avatar.landmark_vertices[468], 0] < 0 < avatar.vertices[avatar.landmark_vertices[473], 0]

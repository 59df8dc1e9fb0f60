"""``Renderer``: a FaceRig drawn by OpenGL with automatic wrinkles.

The mesh is deformed in NumPy (morphs over the active weights, translation-only
skinning: ~0.15 ms) and travels to the GL once per frame with each vertex's wrinkle-map
weights, so the vertex stage only transforms: on a software GL such as llvmpipe, the
shader's morph loop and per-joint uniform indexing cost ~12% of a frame. Uniforms
carry the head pose, lights and zone weights; textures are uploaded once.

Wrinkle maps are uploaded as Jimenez's partial derivatives, two maps per RGBA16F layer, so
the ``auto`` driver adds one texture fetch per pixel. A frame is two draws: the face skin
with its normal and wrinkle maps, then everything else (eyes, mouth, the head beyond the
face) with a program compiled without them, since a software GL runs every side of a
branch and would run the maps' code for every pixel. A rig with glTF alpha modes
(``FaceRig.alpha_mode``) adds those two draws again for its MASK triangles (discarded
below the cutoff) and then for its BLEND ones (blended, depth not written, sorted back
to front each frame). The influence view can come out of
the shaded draw itself (``influence_output``: a second colour attachment), so a
compare video costs one rasterization per frame, not two. Images are rasterized with the
projection's y flipped, so GL's bottom-up rows read back top-down without a copy.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import moderngl
import numpy as np

from capture2face import camera
from capture2face.errors import CaptureError
from capture2face.render.context import gl_context, gl_renderer, software_gl
from capture2face.render.dynamic import dynamic_wrinkle_weights
from capture2face.render.normal_blend import wrinkle_pd_layers
from capture2face.render.shaders import program
from capture2face.render.skinning import Deformer
from capture2face.rig.face_rig import FaceRig
from capture2face.rig.influences import rig_influences, zone_weights

WRINKLE_DRIVERS = ("auto", "zones", "dynamic", "off")
NORMAL_BLENDS = ("pd", "oat")
VIEWS = ("shaded", "influence")
MAX_MAPS = 4  # wrinkle maps travel as a vec4 per vertex

# Camera space, towards the key light: raking from above right (elevation 40 deg, 35 deg to
# the side) so wrinkles read.
DEFAULT_LIGHT_DIRECTION = (0.44, 0.64, 0.63)
DEFAULT_LIGHT_COLOR = (1.15, 1.1, 1.05)
DEFAULT_FILL_COLOR = (0.16, 0.18, 0.22)
DEFAULT_AMBIENT = (0.10, 0.10, 0.12)
# Influence view colours by wrinkle-map name (others fall back by slot).
MAP_COLORS = {"stretch": (0.10, 0.55, 1.00), "compress": (1.00, 0.30, 0.05)}
SLOT_COLORS = [(0.10, 0.55, 1.00), (1.00, 0.30, 0.05), (0.20, 0.90, 0.20), (0.90, 0.20, 0.90)]

# Texture units.
_UNIT_ALBEDO, _UNIT_NORMAL, _UNIT_WRINKLE, _UNIT_MASK0, _UNIT_MASK1 = range(5)
_GL_SRGB8_ALPHA8 = 0x8C43
_UNIT_SCENE = 0  # FXAA pass
_FLIP_Y = np.diag([1.0, -1.0, 1.0, 1.0])
# Shader defines of each glTF alpha mode (FaceRig.alpha_mode: 0 OPAQUE, 1 MASK, 2 BLEND).
_ALPHA_DEFINES = {0: (), 1: (("ALPHA_MASK", 1), ("MIP_SCALE", 0.25)), 2: (("ALPHA_BLEND", 1),)}


@dataclass
class RenderOptions:
    """How to render.

    Attributes:
        size: output size, one int for a square image or ``(width, height)``.
        wrinkles: wrinkle driver: ``auto`` (Dutreve bone masks), ``zones`` (Oat/Jimenez
            mask zones), ``dynamic`` (Oat area change), ``off``.
        normal_blend: ``pd`` (Jimenez partial derivatives) or ``oat`` (Oat's detail blend).
        view: ``shaded``, or ``influence`` (each wrinkle map's per-pixel weight as colour).
        samples: MSAA samples (1 = none).
        fxaa: a screen-space FXAA pass after the render, over the mesh's screen box
            (meant for ``samples=1``: on software GL such as llvmpipe, 4x MSAA costs
            ~2.3x the single-sample draw, FXAA ~1.25x).
        influence_output: ``view="shaded"`` only: also draw the influence view in the same
            pass (second colour attachment), for :meth:`Renderer.render_with_influence`.
            With ``wrinkles="off"`` it shows the ``auto`` driver's weights (what it would
            apply), while the shading stays without wrinkles.
        fov_y_degrees: vertical field of view.
        background: sRGB background colour in [0, 1].
    """

    size: int | tuple[int, int] = 512
    wrinkles: str = "auto"
    normal_blend: str = "pd"
    view: str = "shaded"
    samples: int = 4
    fxaa: bool = False
    influence_output: bool = False
    fov_y_degrees: float = 30.0
    background: tuple = (0.12, 0.12, 0.14)

    @property
    def width_height(self) -> tuple[int, int]:
        return camera._size(self.size)

    def validate(self) -> None:
        """The wrinkle driver, normal blend and view are known ones (one line ``CaptureError``)."""
        _check(self.wrinkles, WRINKLE_DRIVERS, "wrinkle driver")
        _check(self.normal_blend, NORMAL_BLENDS, "normal blend")
        _check(self.view, VIEWS, "view")


@dataclass
class FrameState:
    """One frame to draw.

    Attributes:
        bone_positions: (B, 3) bone positions, head coordinates (cm).
        blend_weights: (M,) morph weights.
        head_pose: (4, 4) head -> camera transform (cm).
        influences: (P, B) per-bone reference-pose influences for the ``auto`` driver;
            None computes them from ``bone_positions`` (grouped, Dutreve §5.1).
        zone_weights: (8,) zone weights in [-1, 1] for the ``zones`` driver; None computes
            them from ``blend_weights`` through the rig's zone table.
        light_direction: (3,) camera-space direction towards the key light; None = default.
        light_color: (3,) linear key-light colour; None = default.
        ambient: (3,) linear ambient colour; None = default.
        head_rotation: (3, 3) rotation of the head joint's vertices about it, for a rig
            with ``head_weights`` (the camera, ``head_pose``, then keeps the body still);
            None: no turn of the head within the rig.
        eye_rotation: (2, 2) yaw, pitch (degrees) of the right and left eye
            (``Animation.eye_rotation``); None = straight ahead.
    """

    bone_positions: np.ndarray
    blend_weights: np.ndarray
    head_pose: np.ndarray
    influences: np.ndarray | None = None
    zone_weights: np.ndarray | None = None
    light_direction: np.ndarray | None = None
    light_color: np.ndarray | None = None
    ambient: np.ndarray | None = None
    head_rotation: np.ndarray | None = None
    eye_rotation: np.ndarray | None = None

    @classmethod
    def at_pose(cls, rig: FaceRig, head_pose: np.ndarray, pose: str | None = None) -> FrameState:
        """The rest pose (``pose=None``) or reference pose ``pose`` with its morph weights."""
        if pose is None:
            return cls(rig.bone_rest.copy(), np.zeros(rig.n_morphs, np.float32), np.asarray(head_pose))
        k = rig.pose_index(pose)
        return cls(rig.pose_bones[k].copy(), rig.pose_morph_weights[k].copy(), np.asarray(head_pose))


def _check(value: str, allowed: tuple[str, ...], what: str) -> str:
    if value not in allowed:
        raise CaptureError(f"unknown {what} '{value}'; choose one of {', '.join(allowed)}")
    return value


def _set(programs: moderngl.Program | tuple[moderngl.Program, ...], name: str, value) -> None:
    """Set a uniform in each program that kept it (unused ones are optimized away)."""
    for prog in programs if isinstance(programs, tuple) else (programs,):
        uniform = prog.get(name, None)
        if uniform is None:
            continue
        if isinstance(value, np.ndarray):
            uniform.write(np.ascontiguousarray(value).tobytes())
        else:
            uniform.value = value


def _mat(m: np.ndarray) -> np.ndarray:
    """Row-major NumPy matrix -> column-major float32 for GL."""
    return np.asarray(m, np.float32).T


class Renderer:
    """Draws one rig with fixed options; use :meth:`create_from_options` as a context manager."""

    def __init__(self, rig: FaceRig, options: RenderOptions | None = None):
        options = options or RenderOptions()
        options.validate()
        self.rig = rig
        self.options = options
        self.ctx = gl_context()
        self._software = software_gl()
        self._resources: list = []
        try:
            self._setup()
        except BaseException:
            self.close()
            raise

    @classmethod
    def create_from_options(cls, rig: FaceRig, options: RenderOptions | None = None) -> Renderer:
        return cls(rig, options)

    # ---- setup --------------------------------------------------------------------
    def _keep(self, obj):
        self._resources.append(obj)
        return obj

    def _setup(self) -> None:
        """Everything a frame needs, built once: the wrinkle driver, the programs, the
        mesh's buffers, the textures and the framebuffers."""
        rig, opts = self.rig, self.options
        shade_wrinkles = opts.wrinkles != "off"
        self._setup_driver()
        self._setup_programs(shade_wrinkles)
        self._setup_mesh()
        self._setup_textures(shade_wrinkles)
        self._setup_targets()
        self._face_size = rig.face_size()
        self._face_centre = camera.face_centre_and_height(rig)[0]

    def _setup_driver(self) -> None:
        """The wrinkle driver (``_driver``), the influence view's map colours and the
        driver's per-map slot and pose tables."""
        rig, opts = self.rig, self.options
        # Influence-view colour of each wrinkle map (by name, else by slot); uploaded per
        # frame because renderers of other rigs may share the compiled program.
        self._map_colors = np.array(SLOT_COLORS, np.float32)
        for k, name in enumerate(rig.wrinkle_map_names[:MAX_MAPS]):
            self._map_colors[k] = MAP_COLORS.get(name, SLOT_COLORS[k])
        n_maps = len(rig.wrinkle_map_names)
        self._influence_output = bool(opts.influence_output) and opts.view == "shaded"
        # The driver that computes the per-pixel map weights: "off" still has the auto
        # weights when they are shown in the influence output.
        driver = "auto" if opts.wrinkles == "off" and self._influence_output else opts.wrinkles
        self._driver = driver
        if driver != "off" and n_maps > MAX_MAPS:
            raise CaptureError(f"rig '{rig.name}' has {n_maps} wrinkle maps; the renderer takes at most {MAX_MAPS}")
        self._slots = {}
        if driver in ("zones", "dynamic"):
            for name in ("stretch", "compress"):
                if name not in rig.wrinkle_map_names:
                    raise CaptureError(f"the '{driver}' wrinkle driver needs a '{name}' wrinkle map; "
                                       f"rig '{rig.name}' has none")
                slot = np.zeros(4, np.float32)
                slot[rig.wrinkle_map_names.index(name)] = 1.0
                self._slots[name] = slot
        # Pose -> wrinkle map, so skinning sums influences straight into map weights.
        self._pose_to_map = np.zeros((len(rig.pose_names), 4), np.float32)
        if driver == "auto" and len(rig.pose_names):
            self._pose_to_map[np.arange(len(rig.pose_names)), rig.pose_maps] = 1.0

    def _setup_programs(self, shade_wrinkles: bool) -> None:
        opts, driver = self.options, self._driver
        face_defines = (
            (f"DRIVER_{driver.upper()}", 1), ("N_MAPS", len(self.rig.wrinkle_map_names)),
            ("SHADE_WRINKLES", int(shade_wrinkles)),
            (f"BLEND_{opts.normal_blend.upper()}", 1), (f"VIEW_{opts.view.upper()}", 1),
        ) + ((("INFLUENCE_OUTPUT", 1),) if self._influence_output else ())
        # Two programs: the face skin's with its normal and wrinkle maps, and one without
        # them for the eyes, mouth and the head beyond the face; each again for MASK and
        # BLEND materials where the rig has them (glTF's alpha modes).
        modes = [0] if self.rig.alpha_mode is None else sorted(int(m) for m in np.unique(self.rig.alpha_mode))
        self._programs_by = {(skin, mode): program("face.vert", "face.frag", face_defines + (("FACE_SKIN", skin),)
                                                    + _ALPHA_DEFINES[mode])
                             for mode in modes for skin in (1, 0)}
        self._programs = tuple(self._programs_by.values())

    def _setup_mesh(self) -> None:
        rig, ctx = self.rig, self.ctx
        # Mesh: the deformed positions, normals and (auto, dynamic) per-vertex map weights
        # in one buffer written per frame; the rest uploaded once.
        self._deformer = Deformer(rig)
        self._vertex_weights = self._driver in ("auto", "dynamic")
        self._frame_vertices = np.zeros((rig.n_vertices, 10 if self._vertex_weights else 6), np.float32)
        self._frame_buffer = self._keep(ctx.buffer(reserve=self._frame_vertices.nbytes))
        layout = "3f 3f 4f" if self._vertex_weights else "3f 3f"
        names = ("in_position", "in_normal") + (("in_map_weight",) if self._vertex_weights else ())
        f4 = lambda a: self._keep(ctx.buffer(np.ascontiguousarray(a, np.float32).tobytes()))  # noqa: E731
        bufs = [
            (self._frame_buffer, layout, *names),
            (f4(rig.tangents), "4f", "in_tangent"),
            (f4(rig.uvs), "2f", "in_uv"),
            (f4(rig.material), "1f", "in_material"),
        ]
        if rig.alpha_cutoff is not None:
            bufs.append((f4(rig.alpha_cutoff), "1f", "in_alpha_cutoff"))
        # Opaque, then MASK, then BLEND triangles (glTF draws blended ones over the rest);
        # in each, the face skin's first, then the rest, each run drawn with its program.
        # A triangle's material and alpha mode are its last vertex's (GL's provoking
        # vertex for the flat varyings).
        last = rig.triangles[:, 2]
        skin = np.where(np.asarray(rig.material)[last] == 0, 1, 0)
        mode = np.zeros(len(last), np.int64) if rig.alpha_mode is None else np.asarray(rig.alpha_mode, np.int64)[last]
        keys = list(self._programs_by)  # (skin, mode): by mode, skin first
        lookup = np.zeros((2, 3), np.int64)
        for k, (s, m) in enumerate(keys):
            lookup[s, m] = k
        group = lookup[skin, mode]
        order = np.argsort(group, kind="stable")
        triangles = np.ascontiguousarray(rig.triangles[order], np.int32)
        self._index = index = self._keep(ctx.buffer(triangles.tobytes()))
        counts = np.bincount(group, minlength=len(keys))
        firsts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self._draws = [(self._keep(ctx.vertex_array(self._programs_by[key], bufs, index_buffer=index,
                                                    index_element_size=4, skip_errors=True)),
                        3 * int(first), 3 * int(count), key[1])
                       for key, first, count in zip(keys, firsts, counts) if count]
        # BLEND runs are sorted back to front each frame: (first triangle, its triangles).
        self._blend_runs = [(int(first), triangles[first:first + count]) for key, first, count
                            in zip(keys, firsts, counts) if count and key[1] == 2]
        self._positions = None  # this frame's deformed positions, for the FXAA scissor box

    def _setup_textures(self, shade_wrinkles: bool) -> None:
        rig, ctx = self.rig, self.ctx
        # Colour and normal maps (row 0 = top = v 0, the glTF convention, uploaded as is).
        albedo = rig.albedo if rig.alpha is None else np.concatenate([rig.albedo, rig.alpha[:, :, None]], axis=2)
        self._textures = [
            (self._image_texture(albedo, internal_format=_GL_SRGB8_ALPHA8), _UNIT_ALBEDO),
            (self._image_texture(rig.normal_map), _UNIT_NORMAL),
        ]
        if shade_wrinkles and len(rig.wrinkle_map_names):
            layers = wrinkle_pd_layers(rig.wrinkle_maps)
            k, h, w, _ = layers.shape
            tex = self._keep(ctx.texture_array((w, h, k), 4, layers.tobytes(), dtype="f2"))
            self._mipmapped(tex)
            self._textures.append((tex, _UNIT_WRINKLE))
        if self._driver == "zones":
            self._textures.append((self._image_texture(rig.zone_masks[..., :4]), _UNIT_MASK0))
            self._textures.append((self._image_texture(rig.zone_masks[..., 4:8]), _UNIT_MASK1))

    def _setup_targets(self) -> None:
        """Framebuffers. ``_target`` is drawn into (multisampled when ``samples`` > 1, then
        blitted into ``_single``); ``_single`` holds the single-sample images: attachment 0
        the view (FXAA's input texture with ``fxaa``), 1 the influence output. With FXAA
        the view is read from ``_fxaa_out``."""
        ctx, opts = self.ctx, self.options
        size = opts.width_height
        self._size = size
        self._rgba = np.empty((size[1], size[0], 4), np.uint8)  # read-back buffer
        samples = max(1, min(int(opts.samples), ctx.max_samples))
        n_colors = 2 if self._influence_output else 1
        rb = lambda s=0: self._keep(ctx.renderbuffer(size, 4, samples=s))  # noqa: E731
        self._fxaa = None
        if opts.fxaa:
            self._scene_tex = self._keep(ctx.texture(size, 4))
            self._scene_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._scene_tex.repeat_x = self._scene_tex.repeat_y = False
            # The image is copied (blitted) to the output, then two passes: one marks the
            # edge pixels in a depth buffer, the other blends along the edges with the
            # early depth test skipping every other block.
            self._scene_only = self._keep(ctx.framebuffer(color_attachments=[self._scene_tex]))
            self._fxaa_mark = program("fullscreen.vert", "fxaa.frag", (("MARK_EDGES", 1),))
            self._fxaa = program("fullscreen.vert", "fxaa.frag")
            self._fxaa_mark_vao = self._keep(ctx.vertex_array(self._fxaa_mark, []))
            self._fxaa_vao = self._keep(ctx.vertex_array(self._fxaa, []))
            self._fxaa_out = self._keep(ctx.framebuffer(color_attachments=[rb()],
                                                        depth_attachment=self._keep(ctx.depth_renderbuffer(size))))
        single = [self._scene_tex if opts.fxaa else rb()] + [rb() for _ in range(n_colors - 1)]
        if samples > 1:
            self._target = self._keep(ctx.framebuffer(
                color_attachments=[rb(samples) for _ in range(n_colors)],
                depth_attachment=self._keep(ctx.depth_renderbuffer(size, samples=samples))))
            self._single = self._keep(ctx.framebuffer(color_attachments=single))
        else:
            self._target = self._single = self._keep(ctx.framebuffer(
                color_attachments=single, depth_attachment=self._keep(ctx.depth_renderbuffer(size))))

    def _mipmapped(self, tex) -> None:
        # Face atlases do not tile: clamp, so filtering at u, v = 0 or 1 never wraps around.
        tex.repeat_x = tex.repeat_y = False
        tex.build_mipmaps()
        # Trilinear filtering and anisotropy are free on GPUs; on llvmpipe, one mip level
        # (bilinear) cuts a frame's work by ~16% and anisotropy would triple it.
        tex.filter = (moderngl.LINEAR_MIPMAP_NEAREST if self._software else moderngl.LINEAR_MIPMAP_LINEAR,
                      moderngl.LINEAR)
        tex.anisotropy = 1.0 if self._software else 4.0

    def _image_texture(self, image: np.ndarray, internal_format: int | None = None):
        """A mipmapped texture of an (H, W, C) uint8 image. RGB images travel as RGBA:
        llvmpipe samples 4-byte texels faster (a frame ~2% faster with the normal map's)."""
        if image.shape[2] == 3:
            image = np.concatenate([image, np.full(image.shape[:2] + (1,), 255, np.uint8)], axis=2)
        h, w, c = image.shape
        kwargs = {"internal_format": internal_format} if internal_format else {}
        tex = self._keep(self.ctx.texture((w, h), c, np.ascontiguousarray(image, np.uint8).tobytes(), **kwargs))
        self._mipmapped(tex)
        return tex

    # ---- per-frame uniforms ---------------------------------------------------------
    def _frame_uniforms(self, state: FrameState) -> None:
        rig, opts, prog = self.rig, self.options, self._programs
        pose = np.asarray(state.head_pose, np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"head_pose must be (4, 4), got {pose.shape}")
        depth = -(pose[:3, :3] @ self._face_centre + pose[:3, 3])[2]
        near = max(0.5, depth - 2.0 * self._face_size)
        far = max(depth, near) + 2.0 * self._face_size
        width, height = self._size
        _set(prog, "u_model_view", _mat(pose))
        _set(prog, "u_normal_matrix", _mat(np.linalg.inv(pose[:3, :3]).T))
        # y flipped: GL's bottom-up rows then read back top-down, no flip on the CPU.
        projection = _FLIP_Y @ camera.perspective(opts.fov_y_degrees, width / height, near, far)
        _set(prog, "u_projection", _mat(projection))
        self._clip_from_head = projection @ pose

        light = np.asarray(state.light_direction if state.light_direction is not None else DEFAULT_LIGHT_DIRECTION,
                           np.float64)
        light = light / np.linalg.norm(light)
        fill = np.array([-light[0], 0.3 * light[1], light[2]])  # per frame, not per pixel
        _set(prog, "u_light_direction", tuple(light))
        _set(prog, "u_fill_direction", tuple(fill / np.linalg.norm(fill)))
        _set(prog, "u_light_color",
             tuple(map(float, state.light_color if state.light_color is not None else DEFAULT_LIGHT_COLOR)))
        _set(prog, "u_ambient", tuple(map(float, state.ambient if state.ambient is not None else DEFAULT_AMBIENT)))
        _set(prog, "u_fill_color", DEFAULT_FILL_COLOR)
        _set(prog, "u_map_color", self._map_colors)
        for tex, unit in self._textures:
            tex.use(unit)
        for name, unit in (("u_albedo", _UNIT_ALBEDO), ("u_normal_map", _UNIT_NORMAL), ("u_wrinkle_pd", _UNIT_WRINKLE),
                           ("u_zone_mask0", _UNIT_MASK0), ("u_zone_mask1", _UNIT_MASK1)):
            _set(prog, name, unit)

        positions, normals = self._deformer(state.bone_positions, state.blend_weights,
                                            eye_rotation=state.eye_rotation, head_rotation=state.head_rotation)
        self._positions = positions
        vertices = self._frame_vertices
        vertices[:, 0:3] = positions
        vertices[:, 3:6] = normals
        driver = self._driver
        if driver == "auto":
            infl = state.influences
            if infl is None:
                infl = rig_influences(np.asarray(state.bone_positions)[None], rig)[0]
            infl = np.asarray(infl, np.float32)
            if infl.shape != (len(rig.pose_names), rig.n_bones):
                raise ValueError(f"influences must be ({len(rig.pose_names)}, {rig.n_bones}), got {infl.shape}")
            # Dutreve 5.2: Inf(v, P_k) = sum_i w_vi * I_Pk(J_i), summed per wrinkle map.
            vertices[:, 6:10] = self._deformer.skin(infl.T @ self._pose_to_map)
        elif driver == "zones":
            zones = state.zone_weights
            if zones is None:
                zones = zone_weights(np.asarray(state.blend_weights)[None], rig.zone_table)[0]
            zones = np.asarray(zones, np.float32).ravel()
            if zones.shape != (8,):
                raise ValueError(f"zone_weights must be (8,), got {zones.shape}")
            _set(prog, "u_zone_weight", zones)
            _set(prog, "u_stretch_slot", tuple(self._slots["stretch"]))
            _set(prog, "u_compress_slot", tuple(self._slots["compress"]))
        elif driver == "dynamic":
            # Oat: smoothed area change per vertex, + compress / - stretch.
            amount = dynamic_wrinkle_weights(rig, positions).astype(np.float32)[:, None]
            vertices[:, 6:10] = (np.maximum(-amount, 0.0) * self._slots["stretch"]
                                 + np.maximum(amount, 0.0) * self._slots["compress"])
        self._frame_buffer.write(vertices)
        for first, tris in self._blend_runs:
            # Farthest first (camera space z: the camera looks down -z).
            depth = positions[tris].sum(1) @ pose[2, :3].astype(np.float32)
            self._index.write(np.ascontiguousarray(tris[np.argsort(depth, kind="stable")]).tobytes(),
                              offset=12 * first)

    # ---- public API -------------------------------------------------------------------
    @property
    def gl_renderer(self) -> str:
        return gl_renderer()  # the renderer draws in the shared context

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the rendered images."""
        return self._size

    def deformed_positions(self, state: FrameState) -> np.ndarray:
        """(V, 3) float32 deformed positions in head coordinates: the mesh the renderer
        draws for ``state``."""
        return self._deformer.positions(state.bone_positions, state.blend_weights,
                                        eye_rotation=state.eye_rotation, head_rotation=state.head_rotation)

    def _draw(self, state: FrameState) -> None:
        ctx = self.ctx
        self._frame_uniforms(state)
        self._target.use()
        self._target.clear(*map(float, self.options.background), 1.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        if not self.rig.double_sided:
            # The projection's y is flipped (see _frame_uniforms), which turns the
            # outward, counter-clockwise triangles clockwise on screen.
            ctx.front_face = "cw"
            ctx.cull_face = "back"
            ctx.enable(moderngl.CULL_FACE)
        for vao, first, count, mode in self._draws:
            if mode == 2:  # BLEND: over what is drawn, without hiding what comes after
                ctx.enable(moderngl.BLEND)
                ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
                self._target.depth_mask = False
                self._target.use()
            vao.render(moderngl.TRIANGLES, vertices=count, first=first)
        if not self._target.depth_mask:
            self._target.depth_mask = True
            self._target.use()
            ctx.disable(moderngl.BLEND)
        ctx.disable(moderngl.CULL_FACE)
        if self._target is not self._single:
            ctx.copy_framebuffer(self._single, self._target)  # MSAA resolve, every attachment
        if self._fxaa is not None:
            # The whole image to the output (a blit), then FXAA over the mesh's screen box:
            # outside it the image is the flat background, which FXAA leaves as it is.
            self._fxaa_out.scissor = None
            self._fxaa_out.use()  # the scissor test off for the blit too
            ctx.copy_framebuffer(self._fxaa_out, self._scene_only)
            self._scene_tex.use(_UNIT_SCENE)
            for prog in (self._fxaa_mark, self._fxaa):
                _set(prog, "u_scene", _UNIT_SCENE)
                _set(prog, "u_texel", (1.0 / self._size[0], 1.0 / self._size[1]))
            # Pass 1 writes depth alone, 1 at edges and 0 elsewhere (over the box: no clear
            # needed); pass 2, at depth 0.5, shades where '<' passes: the edges. (A
            # framebuffer's colour mask and scissor reach GL when it is used.)
            self._fxaa_out.scissor = self._screen_box(state)
            self._fxaa_out.color_mask = (False, False, False, False)
            self._fxaa_out.use()
            ctx.depth_func = "1"
            self._fxaa_mark_vao.render(moderngl.TRIANGLES, vertices=3)
            self._fxaa_out.color_mask = (True, True, True, True)
            self._fxaa_out.use()
            ctx.depth_func = "<"
            self._fxaa_vao.render(moderngl.TRIANGLES, vertices=3)

    def _screen_box(self, state: FrameState) -> tuple[int, int, int, int] | None:
        """(x, y, w, h) window rectangle holding every pixel of the mesh drawn this frame
        (after :meth:`_frame_uniforms`; its projected vertices' box, 2 pixels wider: FXAA reads the diagonal
        neighbours), or None when that is the whole frame or a vertex is behind the eye."""
        positions = self._positions
        clip = positions @ self._clip_from_head[:, :3].T + self._clip_from_head[:, 3]  # (V, 4)
        if (clip[:, 3] <= 1e-6).any():
            return None
        ndc = clip[:, :2] / clip[:, 3:4]
        size = np.array(self._size)
        x0, y0 = np.maximum(np.floor((ndc.min(0) + 1) * 0.5 * size) - 2, 0).astype(int)
        x1, y1 = np.minimum(np.ceil((ndc.max(0) + 1) * 0.5 * size) + 2, size).astype(int)
        if x0 <= 0 and y0 <= 0 and x1 >= size[0] and y1 >= size[1]:
            return None
        return int(x0), int(y0), int(max(x1 - x0, 0)), int(max(y1 - y0, 0))

    def _read(self, framebuffer, attachment: int = 0) -> np.ndarray:
        # RGBA comes back as is, where GL's RGB read converts pixel by pixel (on llvmpipe
        # 0.27 ms a 512x512 read, against 0.02 + OpenCV's 0.08 ms to drop the alpha).
        framebuffer.read_into(self._rgba, components=4, attachment=attachment, alignment=1)
        return cv2.cvtColor(self._rgba, cv2.COLOR_RGBA2RGB)  # a fresh array: callers queue it

    def render(self, state: FrameState) -> np.ndarray:
        """Draw one frame: (H, W, 3) uint8 sRGB, row 0 at the top."""
        self._draw(state)
        return self._read(self._fxaa_out if self._fxaa is not None else self._single)

    def render_with_influence(self, state: FrameState) -> tuple[np.ndarray, np.ndarray]:
        """Draw one frame once: ``(view, influence)``, both (H, W, 3) uint8 sRGB; the
        influence view (as ``view="influence"`` draws it; MSAA applies to it, FXAA does
        not) comes from the draw's second colour attachment. Needs
        ``influence_output=True``."""
        if not self._influence_output:
            raise ValueError("render_with_influence needs RenderOptions(view='shaded', influence_output=True)")
        image = self.render(state)
        return image, self._read(self._single, 1)

    def close(self) -> None:
        """Release the GL objects of this renderer (the shared context and programs stay)."""
        for obj in reversed(self._resources):
            obj.release()
        self._resources.clear()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

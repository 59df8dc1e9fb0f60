"""Smooth random performances of a ``FaceRig``: bones, morph weights, head pose, light.

Pure functions over arrays. A performance is built from keyframes a random 0.5-1.5 s
apart, each a random mixture of the rig's reference poses plus small per-bone offsets,
a few morph weights, a head orientation and a light direction. Keys are interpolated
with a monotone cubic (PCHIP): C1-smooth, exact at the keys and never overshooting, so
angles stay inside their limits, weights inside [0, 1], and a key repeated over a few
frames (a *hold*) is reproduced exactly on every one of them. Three holds are always
present when ``expression=True``: neutral at the very start (so a tracker's automatic
neutral-frame search finds it), then the "stretch" and the "compress" reference poses.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy.interpolate import PchipInterpolator

from capture2face.camera import face_centre_and_height, framing_distance
from capture2face.errors import CaptureError
from capture2face.maths.rotations import rotation_ypr
from capture2face.rig.face_rig import FaceRig
from capture2face.rig.features import smoothstep

# MediaPipe's geometry pipeline assumes this vertical field of view (degrees) for its
# facial transformation matrix; rendering with it makes the tracker's head pose comparable.
DEFAULT_FOV_Y = 63.0

YAW_LIMIT, PITCH_LIMIT, ROLL_LIMIT = 20.0, 20.0, 10.0  # degrees
# Gaze at the keys: within the range people look without turning the head (degrees).
GAZE_YAW_LIMIT, GAZE_PITCH_LIMIT = 25.0, 15.0
GAZE_STRAIGHT = 0.3  # fraction of keys looking straight ahead
VERGENCE_DEG = 2.0  # the eyes' yaws differ by up to this much
TRANSLATION_LIMIT = 0.06  # of the face height, per axis
HOLD_SECONDS = 0.15  # how long neutral and each reference pose are held

# key_pose labels (per frame): no key / neutral / reference pose p is KEY_POSE0 + p.
KEY_FREE, KEY_NEUTRAL, KEY_POSE0 = -1, 0, 1


@dataclass
class Performance:
    """A synthetic performance. F frames, B bones, M morphs.

    Attributes:
        times: (F,) float64 seconds, frame f at f / fps.
        fps: frame rate.
        fov_y: vertical field of view (degrees) ``head_pose`` was framed for.
        bone_positions: (F, B, 3) float32 bone positions, head coordinates (cm).
        blend_weights: (F, M) float32 morph weights in [0, 1], ``rig.morph_names`` order.
        head_angles: (F, 3) float32 yaw, pitch, roll in degrees (about head y, x, z).
        head_offset: (F, 3) float32 translation (cm, camera axes) added to the framing.
        head_pose: (F, 4, 4) float32 head -> camera transform (cm, OpenGL camera).
        light_direction: (F, 3) float32 unit vector towards the light, camera coordinates.
        key_pose: (F,) int8 ``KEY_NEUTRAL`` on frames held exactly at neutral,
            ``KEY_POSE0 + p`` on frames held exactly at reference pose p, else ``KEY_FREE``.
        exiting: (F,) bool, frames where the head is moved out of frame (``face_exit``).
        eye_rotation: (F, 2, 2) float32 yaw, pitch (degrees) of the right and left eye,
            ``Animation.eye_rotation``'s convention; 0 (straight ahead) on neutral holds.
    """

    times: np.ndarray
    fps: float
    fov_y: float
    bone_positions: np.ndarray
    blend_weights: np.ndarray
    head_angles: np.ndarray
    head_offset: np.ndarray
    head_pose: np.ndarray
    light_direction: np.ndarray
    key_pose: np.ndarray
    exiting: np.ndarray
    eye_rotation: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])


# ---- head pose ------------------------------------------------------------------------

def head_poses(rig: FaceRig, angles_deg: np.ndarray, offset: np.ndarray, fov_y: float = DEFAULT_FOV_Y) -> np.ndarray:
    """``camera.framing_pose`` for each frame's angles, translated by ``offset``.

    Args:
        angles_deg: (F, 3) yaw, pitch, roll.
        offset: (F, 3) cm, camera axes.
    Returns:
        (F, 4, 4) float32 head -> camera transforms.
    """
    centre, _ = face_centre_and_height(rig)
    rot = rotation_ypr(angles_deg)  # (F, 3, 3)
    target = np.array([0.0, 0.0, -framing_distance(rig, fov_y)]) + np.asarray(offset, np.float64)
    pose = np.zeros((len(rot), 4, 4))
    pose[:, :3, :3] = rot
    pose[:, :3, 3] = target - rot @ centre
    pose[:, 3, 3] = 1.0
    return pose.astype(np.float32)


# ---- keyframes ------------------------------------------------------------------------

def key_frames(frames: int, fps: float, rng: np.random.Generator, hold: int, n_holds: int) -> np.ndarray:
    """Frame indices of the free keys: 0 first, frames - 1 last, 0.5-1.5 s apart on
    average, with room reserved for ``n_holds`` holds of ``hold`` frames."""
    span = frames - 1 - n_holds * (hold - 1)
    n_seg = max(n_holds + 1, int(round(span / fps)))
    steps = rng.uniform(0.5, 1.5, n_seg)
    return np.round(np.concatenate([[0.0], np.cumsum(steps)]) / steps.sum() * span).astype(int)


def _mixture(rng: np.random.Generator) -> tuple[float, float]:
    """Amounts (a, b) of the stretch and compress poses; one dominates, never both large."""
    major, minor = rng.uniform(0.15, 0.95), rng.uniform(0.0, 0.25)
    if rng.random() < 0.2:  # some keys near neutral
        major *= 0.3
    minor *= 1.0 - major
    return (major, minor) if rng.random() < 0.5 else (minor, major)


@dataclass
class _PoseSpace:
    """The rig's rest bones and how far its reference poses move them."""

    rest: np.ndarray  # (B, 3) float64 cm
    travel: np.ndarray  # (P, B, 3) float64 cm, each reference pose's bones minus rest
    scale: float  # cm: the largest bone travel, else a tenth of the interocular distance
    si: int  # index of the "stretch" pose
    ci: int  # index of the "compress" pose


@dataclass
class _KeyDraws:
    """The random draws at K keys."""

    ab: np.ndarray  # (K, 2) amounts of the stretch and compress poses
    offsets: np.ndarray  # (K, B, 3) per-bone offsets (cm)
    morphs: np.ndarray  # (K, M) sparse morph weights
    angles: np.ndarray  # (K, 3) yaw, pitch, roll (degrees)
    offset: np.ndarray  # (K, 3) head translation (cm, camera axes)
    light: np.ndarray  # (K, 3) unit light directions
    gaze: np.ndarray  # (K, 2, 2) eye yaw, pitch (degrees)


@dataclass
class Values:
    """The performance's values at N times (its keys, or every frame), float64."""

    bones: np.ndarray  # (N, B, 3) cm, head coordinates
    weights: np.ndarray  # (N, M) morph weights
    angles: np.ndarray  # (N, 3) yaw, pitch, roll (degrees)
    offset: np.ndarray  # (N, 3) head translation (cm, camera axes)
    light: np.ndarray  # (N, 3) light directions
    gaze: np.ndarray  # (N, 2, 2) eye yaw, pitch (degrees)

    def map(self, fn) -> Values:
        """``fn`` applied to every array."""
        return Values(*(fn(getattr(self, f.name)) for f in fields(self)))


@dataclass
class Keys:
    """The performance at its keys: frame indices, values and ``key_pose`` labels."""

    keys: np.ndarray  # (K,) frame indices
    values: Values
    label: np.ndarray  # (K,) KEY_FREE, KEY_NEUTRAL or KEY_POSE0 + p


def _pose_space(rig: FaceRig) -> _PoseSpace:
    rest = rig.bone_rest.astype(np.float64)
    travel = rig.pose_bones.astype(np.float64) - rest  # (P, B, 3)
    scale = float(np.linalg.norm(travel, axis=-1).max()) or 0.1 * rig.interocular()
    return _PoseSpace(rest, travel, scale, rig.pose_index("stretch"), rig.pose_index("compress"))


def _random_draws(rig: FaceRig, rng: np.random.Generator, seed: int, K: int, scale: float) -> _KeyDraws:
    """Random state at every key: pose mixture, per-bone offsets, sparse morphs, head, light.
    The draws' order is the performance's: changing it changes every seed's clip."""
    B, M = rig.n_bones, rig.n_morphs
    ab = np.array([_mixture(rng) for _ in range(K)])  # (K, 2)
    offsets = rng.normal(0.0, 0.06 * scale, (K, B, 3))
    offsets[:, 0] = 0.0  # the root never moves in head coordinates
    morphs = np.zeros((K, M))
    for k in range(K):
        chosen = rng.choice(M, size=min(M, rng.integers(0, 4)), replace=False)
        morphs[k, chosen] = rng.uniform(0.1, 0.7, len(chosen))
    angles, offset = random_head(rig, rng, K)
    light = random_lights(rng, K)
    gaze = random_gaze(np.random.default_rng([seed, 14]), K)  # own stream: the rest stays as it was
    return _KeyDraws(ab, offsets, morphs, angles, offset, light, gaze)


def _key_values(rig: FaceRig, keys: np.ndarray, d: _KeyDraws, space: _PoseSpace, head_motion: bool) -> Keys:
    """Bones and morph weights from each key's pose mixture plus its draws; every key free."""
    ab, travel, si, ci = d.ab, space.travel, space.si, space.ci
    bones = space.rest + ab[:, :1, None] * travel[si] + ab[:, 1:, None] * travel[ci] + d.offsets
    weights = np.clip(d.morphs + ab[:, :1] * rig.pose_morph_weights[si] + ab[:, 1:] * rig.pose_morph_weights[ci], 0, 1)
    label = np.full(len(keys), KEY_FREE)
    settle_head(d.angles, d.offset, head_motion)
    return Keys(keys, Values(bones, weights, d.angles, d.offset, d.light, d.gaze), label)


def random_head(rig: FaceRig, rng: np.random.Generator, K: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) head angles (yaw, pitch, roll, degrees) and (K, 3) offsets (cm) at the keys,
    uniform within the limits (the offsets scaled by the face's height)."""
    angles = rng.uniform(-1.0, 1.0, (K, 3)) * [YAW_LIMIT, PITCH_LIMIT, ROLL_LIMIT]
    _, height = face_centre_and_height(rig)
    offset = rng.uniform(-1.0, 1.0, (K, 3)) * TRANSLATION_LIMIT * height
    return angles, offset


def settle_head(angles: np.ndarray, offset: np.ndarray, head_motion: bool) -> None:
    """In place: a still head without ``head_motion``; the first key near frontal either way."""
    if not head_motion:
        angles[:] = 0.0
        offset[:] = 0.0
    angles[0] *= 0.3  # start near frontal so the tracker locks on at once


def _hold_one_expression(rig: FaceRig, k: Keys, d: _KeyDraws, space: _PoseSpace) -> None:
    """One mild expression, held throughout (``expression=False``)."""
    K, travel, si, ci = len(k.keys), space.travel, space.si, space.ci
    k.values.bones[:] = space.rest + 0.35 * travel[si] + 0.15 * travel[ci] + 0.5 * d.offsets[K // 2]
    k.values.weights[:] = np.clip(0.35 * rig.pose_morph_weights[si] + 0.15 * rig.pose_morph_weights[ci]
                           + 0.5 * d.morphs[K // 2], 0, 1)


def _place_reference_poses(rig: FaceRig, k: Keys, rest: np.ndarray, start: str = "rest") -> None:
    """Neutral on key 0, the reference poses on the free keys nearest evenly spread
    fractions of the clip (clear of the face-exit window in the middle). A performance that
    does not start at rest (``start``) takes its neutral mid-clip and its poses later, so
    that its first seconds are free."""
    keys, values, n_poses = k.keys, k.values, len(rig.pose_names)
    fractions = np.linspace(0.2, 0.85, n_poses) if n_poses > 1 else np.array([0.3])
    slots = [0]
    if start != "rest":
        fractions = np.concatenate([[0.6], np.linspace(0.4, 0.9, n_poses) if n_poses > 1 else [0.8]])
        slots = []
    for fr in fractions:  # interior keys only; there are at least n_poses + 1
        order = np.argsort(np.abs(keys[1:-1] - fr * keys[-1])) + 1
        slots.append(int(next(i for i in order if i not in slots)))
    for p, i in enumerate(slots):
        if p == 0:  # neutral
            values.bones[i], values.weights[i], k.label[i] = rest, 0.0, KEY_NEUTRAL
            values.gaze[i] = 0.0
        else:
            values.bones[i] = rig.pose_bones[p - 1]
            values.weights[i] = rig.pose_morph_weights[p - 1]
            k.label[i] = KEY_POSE0 + p - 1


def hold_labelled_keys(k: Keys, hold: int, frames: int) -> Keys:
    """Hold each labelled key: duplicate it ``hold - 1`` frames later and shift the rest."""
    label = k.label
    dup = np.where(label != KEY_FREE, hold - 1, 0)
    keys = k.keys + np.concatenate([[0], np.cumsum(dup)[:-1]])
    rep = np.where(label != KEY_FREE, 2, 1)
    end_keys = keys + dup
    keys = np.stack([keys, end_keys], 1)[np.arange(2)[None] < rep[:, None]]
    keys[-1] = frames - 1  # absorb rounding
    return Keys(keys, k.values.map(lambda x: np.repeat(x, rep, 0)), np.repeat(label, rep, 0))


def interpolate(k: Keys, f: np.ndarray) -> Values:
    """Monotone cubic (PCHIP) through the keys at frames ``f``; weights clipped to [0, 1],
    light directions normalized."""
    def interp(values: np.ndarray) -> np.ndarray:
        flat = values.reshape(len(values), -1)
        return PchipInterpolator(k.keys, flat, axis=0)(f).reshape((len(f),) + values.shape[1:])

    out = k.values.map(interp)
    out.weights = np.clip(out.weights, 0.0, 1.0)
    out.light /= np.linalg.norm(out.light, axis=1, keepdims=True)
    return out


def exact_holds(k: Keys, c: Values, frames: int) -> np.ndarray:
    """Exact values on held frames (interpolation is exact there up to rounding); returns
    the (F,) ``key_pose`` labels."""
    key_pose = np.full(frames, KEY_FREE, np.int8)
    keys, label, at = k.keys, k.label, k.values
    for i in range(len(keys) - 1):
        if label[i] != KEY_FREE and label[i + 1] == label[i]:
            span = slice(keys[i], keys[i + 1] + 1)
            key_pose[span] = label[i]
            c.bones[span], c.weights[span] = at.bones[i], at.weights[i]
            c.gaze[span] = at.gaze[i]
    return key_pose


# ---- performances that do not start at rest ------------------------------------------------
STARTS = ("rest", "held", "raised")
HELD_MAX_SECONDS = 2.0  # "held": the first expression lasts up to this long...
START_RAMP_SECONDS = 0.3  # ...and eases into the performance over this long
RAISED_AMOUNT = 0.7  # "raised": this share of the stretch pose's brow travel, and...
RAISED_MORPHS = {"browInnerUp": 0.6, "browOuterUpLeft": 0.4, "browOuterUpRight": 0.4}  # ...these morphs


def _start_held(rig: FaceRig, c: Values, key_pose: np.ndarray, d: _KeyDraws, space: _PoseSpace,
                fps: float) -> None:
    """Hold one expression (a frown-like compress mixture plus key 0's own draws) from frame
    0 until before the first labelled hold (at most :data:`HELD_MAX_SECONDS`), easing into
    the performance: the clip does not start at rest."""
    held = np.flatnonzero(key_pose != KEY_FREE)
    end = min(int(held[0]) if held.size else len(key_pose), round(HELD_MAX_SECONDS * fps))
    ramp = max(1, min(round(START_RAMP_SECONDS * fps), end // 3))
    m = 1.0 - smoothstep((np.arange(len(key_pose)) - (end - ramp)) / ramp)  # (F,) 1 held .. 0 free
    bones = space.rest + 0.6 * space.travel[space.ci] + d.offsets[0]
    weights = np.clip(0.6 * rig.pose_morph_weights[space.ci] + d.morphs[0], 0.0, 1.0)
    c.bones[:] = m[:, None, None] * bones + (1.0 - m[:, None, None]) * c.bones
    c.weights[:] = m[:, None] * weights + (1.0 - m[:, None]) * c.weights


def _start_raised(rig: FaceRig, c: Values, key_pose: np.ndarray, space: _PoseSpace, fps: float) -> None:
    """Raise the brows (the stretch pose's brow bones and the brow-raising morphs) on every
    free frame, easing out around the labelled holds, which stay exact."""
    ramp = max(1, round(START_RAMP_SECONDS * fps / 2))
    free = (key_pose == KEY_FREE).astype(np.float64)
    # Erode the free frames by the ramp, then smooth with a box as wide: 0 on and next to the
    # holds, 1 away from them, smooth between.
    eroded = 1.0 - np.convolve(1.0 - free, np.ones(2 * ramp + 1), "same").clip(0.0, 1.0)
    m = np.convolve(np.pad(eroded, ramp, mode="edge"), np.ones(2 * ramp + 1) / (2 * ramp + 1), "valid")
    brow = np.array([n.startswith("brow") for n in rig.bone_names], np.float64)[:, None]  # (B, 1)
    c.bones += m[:, None, None] * (RAISED_AMOUNT * brow * space.travel[space.si])[None]
    cols = {n: i for i, n in enumerate(rig.morph_names)}
    for name, amount in RAISED_MORPHS.items():
        if name in cols:
            c.weights[:, cols[name]] = np.clip(c.weights[:, cols[name]] + amount * m, 0.0, 1.0)


def random_performance(
    rig: FaceRig,
    frames: int,
    seed: int = 0,
    fps: float = 30.0,
    head_motion: bool = True,
    expression: bool = True,
    face_exit: bool = False,
    fov_y: float = DEFAULT_FOV_Y,
    start: str = "rest",
) -> Performance:
    """A smooth random performance of ``frames`` frames, deterministic for ``seed``.

    ``expression=False`` keeps one mild, non-neutral expression throughout (head motion
    only); ``head_motion=False`` keeps the head frontal and centred. ``face_exit=True``
    slides the head out of the (square) frame sideways for about one second mid-clip.
    ``start``: "rest" starts on the neutral hold; "held" holds one expression for the first
    seconds (the neutral hold mid-clip); "raised" keeps the brows raised on every frame but
    the neutral and reference-pose holds (from frame 0): what a real actor's clip may do.
    """
    if frames < 2:
        raise CaptureError(f"a synthetic performance needs at least 2 frames (got {frames})")
    if start not in STARTS:
        raise CaptureError(f"unknown start '{start}' (one of {', '.join(STARTS)})")
    if start != "rest" and not expression:
        raise CaptureError("a performance without expression has no start to choose")
    rng = np.random.default_rng(seed)
    hold = max(2, int(round(HOLD_SECONDS * fps)))
    n_poses = len(rig.pose_names)
    if expression and frames < (n_poses + 1) * (hold + 4):
        raise CaptureError(
            f"{frames} frames are too few to pass through neutral and {n_poses} reference poses"
        )
    space = _pose_space(rig)

    keys = key_frames(frames, fps, rng, hold, n_poses + 1 if expression else 0)
    draws = _random_draws(rig, rng, seed, len(keys), space.scale)
    k = _key_values(rig, keys, draws, space, head_motion)
    if not expression:
        _hold_one_expression(rig, k, draws, space)
    else:
        _place_reference_poses(rig, k, space.rest, start)
        k = hold_labelled_keys(k, hold, frames)

    f = np.arange(frames, dtype=np.float64)
    c = interpolate(k, f)
    key_pose = exact_holds(k, c, frames)
    if start == "held":
        _start_held(rig, c, key_pose, draws, space, fps)
    elif start == "raised":
        _start_raised(rig, c, key_pose, space, fps)

    offset_f, exiting = c.offset, np.zeros(frames, bool)
    if face_exit:
        offset_f, exiting = _face_exit(rig, offset_f, fps, fov_y)
    return Performance(
        times=f / fps,
        fps=float(fps),
        fov_y=float(fov_y),
        bone_positions=c.bones.astype(np.float32),
        blend_weights=c.weights.astype(np.float32),
        head_angles=c.angles.astype(np.float32),
        head_offset=offset_f.astype(np.float32),
        head_pose=head_poses(rig, c.angles, offset_f, fov_y),
        light_direction=c.light.astype(np.float32),
        key_pose=key_pose,
        exiting=exiting,
        eye_rotation=c.gaze.astype(np.float32),
    )


def random_gaze(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 2, 2) yaw, pitch per eye (degrees) at the keys: some straight ahead, the rest
    uniform within the gaze limits, both eyes together up to a small vergence."""
    yaw = rng.uniform(-GAZE_YAW_LIMIT, GAZE_YAW_LIMIT, n)
    pitch = rng.uniform(-GAZE_PITCH_LIMIT, GAZE_PITCH_LIMIT, n)
    straight = rng.random(n) < GAZE_STRAIGHT
    yaw[straight], pitch[straight] = 0.0, 0.0
    verge = rng.uniform(0.0, VERGENCE_DEG, n) * ~straight  # > 0: both eyes turn inwards
    out = np.empty((n, 2, 2))
    out[:, 0, 0], out[:, 1, 0] = yaw + 0.5 * verge, yaw - 0.5 * verge  # right eye in = +x
    out[:, :, 1] = pitch[:, None]
    return out


def random_lights(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) unit directions towards a key light in front of the face: from above and
    to either side, never grazing (a tracker needs the face lit)."""
    azimuth = np.radians(rng.uniform(-40.0, 40.0, n))
    elevation = np.radians(rng.uniform(5.0, 40.0, n))
    return np.stack([np.sin(azimuth) * np.cos(elevation), np.sin(elevation),
                     np.cos(azimuth) * np.cos(elevation)], 1)


def _face_exit(rig: FaceRig, offset: np.ndarray, fps: float, fov_y: float):
    """Slide the head sideways out of the frame for ~1 s in the middle of the clip.

    Returns the new (F, 3) offsets and the (F,) frames where the head is (partly) out.
    """
    frames = len(offset)
    out_len, ramp = int(round(fps)), max(2, int(round(0.2 * fps)))
    if frames < out_len + 2 * ramp + 2 * int(round(0.5 * fps)):
        raise CaptureError(f"{frames} frames are too few for the face to leave the frame and come back")
    start = frames // 2 - out_len // 2
    # Far enough that the whole face is outside the horizontal field of view.
    _, height = face_centre_and_height(rig)
    half_width = framing_distance(rig, fov_y) * np.tan(np.radians(fov_y) / 2)  # square frames
    shift = half_width + height  # the face is narrower than it is tall
    f = np.arange(frames)
    # Smoothstep ramps in and out.
    up = np.clip((f - (start - ramp)) / ramp, 0, 1)
    down = np.clip(((start + out_len + ramp) - f) / ramp, 0, 1)
    s = np.minimum(up, down)
    s = s * s * (3 - 2 * s)
    out = offset.copy()
    out[:, 0] += shift * s
    return out, s > 0

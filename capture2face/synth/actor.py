"""Any ARKit character as the synthetic actor: a random, plausible ARKit performance.

The default avatar's performance (:func:`~capture2face.synth.trajectories.random_performance`)
mixes its reference poses and bone offsets. A character driven by ARKit morphs (an
ICT-FaceKit head, ``drive_mode(rig) == "arkit"``) performs ARKit weights instead, built
from combinations people make:

* **expression keys** a random 0.5-1.5 s apart (as the default's): a smile (mouthSmile with
  cheekSquint and a little eyeSquint), raised brows with widened eyes or lowered brows
  with squinting eyes (and sometimes a nose sneer), a frown, a wide-open jaw with raised
  brows (surprise), now and then a cheek puff or dimples;
* **speech**: mouth keys 0.12-0.35 s apart in talking spells of 1-3 s (jawOpen plus one
  viseme-like mouth shape: funnel, pucker, closed lips, rolls, presses, stretches...),
  silent spells between them;
* **blinks** every 1.5-5 s (0.25 s, both eyes; some winks);
* **gaze** as the default's (``trajectories.random_gaze``): the eyes turn (where the rig
  has turning eyes, :func:`with_turning_eyes`) and the eyeLook weights follow the angles
  (1 at :data:`EYE_LOOK_FULL_DEG`);
* head motion and light as the default's; the neutral held over the first frames (the
  truth's neutral for the retargeting). Bones stay at rest: the morphs deform the face.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.interpolate import interp1d
from scipy.ndimage import uniform_filter1d

from capture2face.calibration.protocol import step_amounts, target_matrix
from capture2face.errors import CaptureError
from capture2face.rig.arkit_names import GAZE_SCORES, arkit_morphs
from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.rig.features import smoothstep
from capture2face.synth.trajectories import (
    DEFAULT_FOV_Y,
    HOLD_SECONDS,
    KEY_FREE,
    KEY_NEUTRAL,
    Keys,
    Performance,
    Values,
    exact_holds,
    head_poses,
    hold_labelled_keys,
    interpolate,
    key_frames,
    random_gaze,
    random_head,
    random_lights,
    settle_head,
)
from capture2face.topology import ARKIT_NAMES, IRIS_CENTRES, N_LANDMARKS

EYE_LOOK_FULL_DEG = 30.0  # an eyeLook weight of 1 turns the eye this far
EYE_MATERIAL = 1  # FaceRig.material of eyeballs
BLINK_EVERY = (1.5, 5.0)  # seconds between blinks
BLINK_CLOSE, BLINK_OPEN = 0.1, 0.15  # seconds to close, to open again
WINK_SHARE = 0.1
SPEECH_SPELL, SILENCE_SPELL = (1.0, 3.0), (0.5, 2.0)  # seconds
SPEECH_KEY_STEP = (0.12, 0.35)  # seconds between mouth keys while talking
ONSET_SECONDS = 0.3  # after the neutral hold, speech and blinks ease in over this long
# Speech-like mouth shapes: name -> (amount range, jawOpen range while it is made).
VISEMES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "": ((0.0, 0.0), (0.1, 0.6)),  # an open vowel
    "mouthFunnel": ((0.3, 0.8), (0.1, 0.35)),
    "mouthPucker": ((0.3, 0.9), (0.0, 0.1)),
    "mouthClose": ((0.1, 0.3), (0.1, 0.3)),  # lips together, jaw a little open (ARKit's meaning)
    "mouthRollLower": ((0.3, 0.8), (0.0, 0.1)),
    "mouthRollUpper": ((0.3, 0.7), (0.0, 0.1)),
    "mouthPress": ((0.3, 0.8), (0.0, 0.05)),
    "mouthStretch": ((0.2, 0.6), (0.1, 0.3)),
    "mouthLowerDown": ((0.2, 0.7), (0.1, 0.4)),
    "mouthUpperUp": ((0.2, 0.6), (0.05, 0.3)),
    "mouthShrugLower": ((0.2, 0.6), (0.0, 0.1)),
    "mouthShrugUpper": ((0.2, 0.5), (0.0, 0.1)),
    "mouthLeft": ((0.2, 0.6), (0.0, 0.2)),
    "mouthRight": ((0.2, 0.6), (0.0, 0.2)),
    "jawLeft": ((0.1, 0.4), (0.1, 0.3)),
    "jawRight": ((0.1, 0.4), (0.1, 0.3)),
    "jawForward": ((0.1, 0.4), (0.05, 0.3)),
}
SIDED = ("mouthPress", "mouthStretch", "mouthLowerDown", "mouthUpperUp")  # both sides alike
_COL = {n: i for i, n in enumerate(ARKIT_NAMES)}


def with_turning_eyes(rig: FaceRig) -> FaceRig:
    """``rig`` with eyes that turn (``eye_centres``, ``eye_vertex_side``): each eyeball
    (the :data:`EYE_MATERIAL` vertices on the side of its iris landmarks 468 / 473) turns
    about the centre of the sphere fitted to it. The rig itself where it has turning eyes
    already, or no eyeballs with iris landmarks on them."""
    eye = np.asarray(rig.material) == EYE_MATERIAL
    if rig.has_eyes or not eye.any() or len(rig.landmark_vertices) < N_LANDMARKS:
        return rig
    iris = landmark_points(rig, rig.vertices, list(IRIS_CENTRES)).astype(np.float64)  # right, left
    if abs(iris[0, 0] - iris[1, 0]) < 1e-6:
        return rig
    mid = 0.5 * (iris[0, 0] + iris[1, 0])
    right_side = np.sign(iris[0, 0] - mid)
    side = np.full(len(rig.vertices), -1, np.int8)
    side[eye] = np.where(np.sign(rig.vertices[eye, 0] - mid) == right_side, 0, 1)
    centres = np.stack([_sphere_centre(rig.vertices[side == s].astype(np.float64)) for s in (0, 1)])
    return dataclasses.replace(rig, eye_centres=centres.astype(np.float32), eye_vertex_side=side)


def _sphere_centre(points: np.ndarray) -> np.ndarray:
    """(3,) least-squares centre of the sphere through (N, 3) points: |p|^2 = 2 c.p + k."""
    a = np.concatenate([2.0 * points, np.ones((len(points), 1))], 1)
    sol, *_ = np.linalg.lstsq(a, (points * points).sum(1), rcond=None)
    return sol[:3]


def _expression_keys(rng: np.random.Generator, K: int) -> np.ndarray:
    """(K, 52) ARKit weights (``ARKIT_NAMES`` order) at the expression keys."""
    w = np.zeros((K, len(ARKIT_NAMES)))
    u = rng.uniform

    def put(rows, name: str, values) -> None:
        w[rows, _COL[name]] = np.maximum(w[rows, _COL[name]], values)

    smile = rng.random(K) < 0.4
    amt, tilt = u(0.3, 1.0, K), u(-0.2, 0.2, K)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        s = np.clip(amt * (1 + sign * tilt), 0, 1)[smile]
        put(smile, "mouthSmile" + side, s)
        put(smile, "cheekSquint" + side, 0.7 * s)
        put(smile, "eyeSquint" + side, 0.3 * s)
    brows = rng.choice(3, K, p=[0.35, 0.25, 0.4])  # raised, lowered, neither
    b, tilt = u(0.3, 1.0, K), u(-0.15, 0.15, K)
    up, down = brows == 0, brows == 1
    put(up, "browInnerUp", b[up])
    sneer = down & (rng.random(K) < 0.4)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        put(up, "browOuterUp" + side, (b * u(0.5, 1.0, K))[up])
        put(up, "eyeWide" + side, (0.5 * b * u(0.4, 1.0, K))[up])
        put(down, "browDown" + side, np.clip(b * (1 + sign * tilt), 0, 1)[down])
        put(down, "eyeSquint" + side, 0.5 * b[down])
        put(sneer, "noseSneer" + side, 0.4 * b[sneer])
    frown = ~smile & (rng.random(K) < 0.2)
    f = u(0.2, 0.7, K)[frown]
    put(frown, "mouthFrownLeft", f)
    put(frown, "mouthFrownRight", f)
    surprise = ~smile & up & (rng.random(K) < 0.3)
    put(surprise, "jawOpen", u(0.5, 1.0, K)[surprise])
    puff, dimple = rng.random(K) < 0.05, smile & (rng.random(K) < 0.2)
    put(puff, "cheekPuff", u(0.4, 1.0, K)[puff])
    put(dimple, "mouthDimpleLeft", u(0.2, 0.6, K)[dimple])
    put(dimple, "mouthDimpleRight", u(0.2, 0.6, K)[dimple])
    return w


def _speech_keys(rng: np.random.Generator, end: float) -> tuple[np.ndarray, np.ndarray]:
    """(K,) key times (seconds, up to past ``end``) and (K, 52) ARKit weights of the speech
    layer: talking spells of mouth keys, each jawOpen plus one :data:`VISEMES` shape,
    between silences (zero keys)."""
    times, values = [0.0], [np.zeros(len(ARKIT_NAMES))]
    t, names = 0.0, list(VISEMES)
    while t < end:
        t += rng.uniform(*SILENCE_SPELL)
        times.append(t)
        values.append(np.zeros(len(ARKIT_NAMES)))
        stop = t + rng.uniform(*SPEECH_SPELL)
        while t < min(stop, end):
            t += rng.uniform(*SPEECH_KEY_STEP)
            key = np.zeros(len(ARKIT_NAMES))
            name = names[rng.integers(len(names))]
            (lo, hi), (jlo, jhi) = VISEMES[name]
            key[_COL["jawOpen"]] = rng.uniform(jlo, jhi)
            amount = rng.uniform(lo, hi)
            for full in (name + "Left", name + "Right") if name in SIDED else (name,) if name else ():
                key[_COL[full]] = amount
            times.append(t)
            values.append(key)
        t += SPEECH_KEY_STEP[1]  # the mouth closes before the next silence
        times.append(t)
        values.append(np.zeros(len(ARKIT_NAMES)))
    return np.asarray(times), np.asarray(values)


def _speech(rng: np.random.Generator, frames: int, fps: float) -> np.ndarray:
    """(F, 52) the speech layer: its keys (:func:`_speech_keys`) joined linearly, then
    rounded by a 0.17 s box (syllables, not a PCHIP through every key: the keys are close)."""
    times, keys = _speech_keys(rng, (frames - 1) / fps)
    out = interp1d(times, keys, axis=0)(np.arange(frames) / fps)
    width = max(1, round(0.08 * fps))
    return uniform_filter1d(out, 2 * width + 1, axis=0, mode="nearest")


def _blinks(rng: np.random.Generator, frames: int, fps: float) -> np.ndarray:
    """(F, 2) eyeBlink (right, left) of blinks every :data:`BLINK_EVERY` seconds."""
    t = np.arange(frames) / fps
    out = np.zeros((frames, 2))
    at = rng.uniform(0.3, BLINK_EVERY[1])
    while at < t[-1]:
        peak = rng.uniform(0.85, 1.0)
        eyes = np.ones(2) if rng.random() >= WINK_SHARE else np.eye(2)[rng.integers(2)]
        shape = np.where(t < at, smoothstep((t - at + BLINK_CLOSE) / BLINK_CLOSE),
                         1.0 - smoothstep((t - at) / BLINK_OPEN))
        out = np.maximum(out, peak * shape[:, None] * eyes[None])
        at += rng.uniform(*BLINK_EVERY)
    return out


def _eye_looks(gaze: np.ndarray) -> np.ndarray:
    """(F, 52) the eyeLook weights of (F, 2, 2) eye yaw, pitch (degrees)."""
    out = np.zeros((len(gaze), len(ARKIT_NAMES)))
    for (eye, angle), (plus, minus) in GAZE_SCORES.items():
        a = gaze[:, eye, angle] / EYE_LOOK_FULL_DEG
        out[:, _COL[plus]] = np.clip(a, 0.0, 1.0)
        out[:, _COL[minus]] = np.clip(-a, 0.0, 1.0)
    return out


def _arkit_frames(rng: np.random.Generator, k: Keys, expression: np.ndarray, frames: int, fps: float,
                  gaze: np.ndarray | None) -> np.ndarray:
    """(F, 52) ARKit weights per frame: expression keys (interpolated by the caller into
    ``expression``), speech and blinks eased in after the neutral hold, eyeLooks of the gaze."""
    held = np.flatnonzero(k.label == KEY_NEUTRAL)
    after = k.keys[held[-1]] if held.size else 0
    onset = smoothstep((np.arange(frames) - after) / max(1.0, ONSET_SECONDS * fps))[:, None]
    w = expression + onset * _speech(rng, frames, fps)
    blinks = onset * _blinks(rng, frames, fps)
    for e, side in enumerate(("Right", "Left")):
        c = _COL["eyeBlink" + side]
        w[:, c] = np.maximum(w[:, c], blinks[:, e])
    if gaze is not None:
        w = np.maximum(w, _eye_looks(gaze))
    w = np.clip(w, 0.0, 1.0)
    w[:, _COL["mouthClose"]] = np.minimum(w[:, _COL["mouthClose"]], w[:, _COL["jawOpen"]])
    return w


def random_arkit_performance(rig: FaceRig, frames: int, seed: int = 0, fps: float = 30.0, head_motion: bool = True,
                             fov_y: float = DEFAULT_FOV_Y) -> Performance:
    """A smooth random ARKit performance of ``rig`` (see the module docstring), deterministic
    for ``seed``: the neutral held over the first :data:`HOLD_SECONDS`, bones at rest.

    Raises:
        CaptureError: the rig has no ARKit-named morphs, or ``frames`` are too few.
    """
    columns = arkit_morphs(rig.morph_names)  # rig morph -> ARKit name
    if not columns:
        raise CaptureError(f"actor '{rig.name}' has no ARKit-named morph targets to perform")
    hold = max(2, round(HOLD_SECONDS * fps))
    if frames < 2 * hold + 4:
        raise CaptureError(f"{frames} frames are too few for an ARKit performance (at least {2 * hold + 4})")
    rng = np.random.default_rng([seed, 22])
    keys = key_frames(frames, fps, rng, hold, 1)
    K = len(keys)
    angles, offset = random_head(rig, rng, K)
    settle_head(angles, offset, head_motion)
    expression = _expression_keys(rng, K)
    expression[0] = 0.0
    gaze = random_gaze(np.random.default_rng([seed, 14]), K)
    gaze[0] = 0.0
    k, c, key_pose = _held_keys(rig, keys, expression, angles, offset, random_lights(rng, K), gaze, hold, frames)
    eyes = c.gaze if rig.has_eyes else None
    arkit = _arkit_frames(rng, k, c.weights, frames, fps, eyes)
    return _arkit_performance(rig, columns, arkit, c, key_pose, fps, fov_y, eyes)


def _held_keys(rig: FaceRig, keys: np.ndarray, weights, angles, offset, light, gaze, hold: int,
               frames: int) -> tuple[Keys, Values, np.ndarray]:
    """The keys at frames ``keys`` (K,) with these (K, ...) values and the bones at rest, the
    first key the neutral held ``hold`` frames: (held keys, their values at every frame,
    ``key_pose`` labels)."""
    K = len(keys)
    label = np.full(K, KEY_FREE)
    label[0] = KEY_NEUTRAL
    bones = np.repeat(rig.bone_rest[None].astype(np.float64), K, 0)
    k = hold_labelled_keys(Keys(keys, Values(bones, weights, angles, offset, light, gaze), label), hold, frames)
    c = interpolate(k, np.arange(frames, dtype=np.float64))
    return k, c, exact_holds(k, c, frames)


def _arkit_performance(rig: FaceRig, columns: dict[int, str], arkit: np.ndarray, c: Values, key_pose: np.ndarray,
                       fps: float, fov_y: float, eyes: np.ndarray | None) -> Performance:
    """The Performance of (F, 52) ARKit weights ``arkit`` on ``rig``'s ``columns`` (morph ->
    ARKit name), the head and light of ``c`` (every frame's values), bones at rest."""
    frames = len(arkit)
    weights = np.zeros((frames, rig.n_morphs))
    for m, name in columns.items():
        weights[:, m] = arkit[:, _COL[name]]
    return Performance(
        times=np.arange(frames, dtype=np.float64) / fps, fps=float(fps), fov_y=float(fov_y),
        bone_positions=np.repeat(rig.bone_rest[None], frames, 0).astype(np.float32),
        blend_weights=weights.astype(np.float32),
        head_angles=c.angles.astype(np.float32),
        head_offset=c.offset.astype(np.float32),
        head_pose=head_poses(rig, c.angles, c.offset, fov_y),
        light_direction=c.light.astype(np.float32),
        key_pose=key_pose,
        exiting=np.zeros(frames, bool),
        eye_rotation=None if eyes is None else eyes.astype(np.float32),
    )

def _gaze_of_looks(w: np.ndarray) -> np.ndarray:
    """(F, 2, 2) eye yaw, pitch (degrees) of (F, 52) ARKit weights' eyeLook columns: the
    inverse of :func:`_eye_looks`."""
    out = np.zeros((len(w), 2, 2))
    for (eye, angle), (plus, minus) in GAZE_SCORES.items():
        out[:, eye, angle] = EYE_LOOK_FULL_DEG * (w[:, _COL[plus]] - w[:, _COL[minus]])
    return out


def rom_performance(rig: FaceRig, seed: int = 0, fps: float = 30.0, head_motion: bool = True,
                    fov_y: float = DEFAULT_FOV_Y) -> Performance:
    """``rig`` performing the range-of-motion protocol
    (:data:`~capture2face.calibration.protocol.PROTOCOL`) on its timing, each step at its
    targets' weights, with the seed's head motion and light (as :func:`random_arkit_performance`'s,
    drawn from another stream, so a ROM take and a performance of one seed differ); the eyes
    turn with the eyeLook steps. The neutral holds the first frames.

    Raises:
        CaptureError: the rig has no ARKit-named morphs.
    """
    columns = arkit_morphs(rig.morph_names)
    if not columns:
        raise CaptureError(f"actor '{rig.name}' has no ARKit-named morph targets to perform")
    arkit = step_amounts(fps) @ target_matrix().T  # (F, 52)
    frames = len(arkit)
    hold = max(2, round(HOLD_SECONDS * fps))
    rng = np.random.default_rng([seed, 32])
    keys = key_frames(frames, fps, rng, hold, 1)
    K = len(keys)
    angles, offset = random_head(rig, rng, K)
    settle_head(angles, offset, head_motion)
    _, c, key_pose = _held_keys(rig, keys, np.zeros((K, len(ARKIT_NAMES))), angles, offset, random_lights(rng, K),
                                np.zeros((K, 2, 2)), hold, frames)
    eyes = _gaze_of_looks(arkit) if rig.has_eyes else None
    return _arkit_performance(rig, columns, arkit, c, key_pose, fps, fov_y, eyes)

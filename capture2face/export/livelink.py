"""``livelink.csv``: the performance as a Live Link Face CSV (Epic's iPhone app format), so
it drives a MetaHuman or any ARKit-named rig.

Header (exactly as the app writes it): ``Timecode,BlendShapeCount`` and 61 columns: the 52
ARKit blendshapes (the app's capitalized spelling and order), head yaw/pitch/roll and the
two eyes' yaw/pitch/roll. Each row: ``HH:MM:SS:FF.fff,61,<61 values>``.

* **Timecode**: the frame's presentation time in the clip as hours:minutes:seconds:frame, the
  frame counted at the clip's nominal rate rounded to an integer (timecode rates are
  integers); ``.fff`` is the sub-frame fraction (0 for a constant-rate clip).
* **Blendshapes** are ARKit curves with ARKit meaning, matched by name case-insensitively:
  ``Animation.arkit_weights`` (0 at the clip's rest, 1 at the full pose: JawOpen 1 = jaw
  fully open, EyeBlink 1 = eye closed; see :mod:`capture2face.retarget.arkit`), else 0
  (MediaPipe has no ``tongueOut``). Never the character's own morph weights: those share
  the motion with its bones and do not mean what ARKit's names mean. An animation saved
  before it had ARKit curves takes them from the clip's Track when one is given, else
  MediaPipe's raw scores. ``_neutral`` is ignored.
* **Angles** are normalized like the app's streamed values and the tools that read its
  CSVs (PyLiveLinkFace, the Blender Live Link Face add-on): -1..1, where 1 is a quarter
  turn (``ANGLE_UNIT_DEG`` = 90 degrees). Signs, in head coordinates (+x the subject's
  left, +y up, +z out of the face): yaw > 0 turns the face / gaze towards the subject's
  left, pitch > 0 tips it down, roll > 0 tilts the head towards the subject's right
  shoulder (rotation about +z). Head angles come from the head pose (rotation = Ry(yaw)
  Rx(pitch) Rz(roll)); eye yaw and pitch from the tracked irises' geometry
  (``Animation.eye_rotation``, degrees, same signs), or, for an animation saved before it
  had them, from MediaPipe's eyeLook* scores, a score of 1 being ``EYE_LOOK_MAX_DEG``
  degrees; eye roll is 0.
"""

from __future__ import annotations

import io
import os

import numpy as np

from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path
from capture2face.maths.rotations import rotation_part
from capture2face.retarget.arkit import arkit_curves
from capture2face.rig.arkit_names import GAZE_SCORES

HEADER = (
    "Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,"
    "EyeLookUpLeft,EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,"
    "EyeLookOutRight,EyeLookUpRight,EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,"
    "JawOpen,MouthClose,MouthFunnel,MouthPucker,MouthRight,MouthLeft,MouthSmileLeft,"
    "MouthSmileRight,MouthFrownLeft,MouthFrownRight,MouthDimpleLeft,MouthDimpleRight,"
    "MouthStretchLeft,MouthStretchRight,MouthRollLower,MouthRollUpper,MouthShrugLower,"
    "MouthShrugUpper,MouthPressLeft,MouthPressRight,MouthLowerDownLeft,MouthLowerDownRight,"
    "MouthUpperUpLeft,MouthUpperUpRight,BrowDownLeft,BrowDownRight,BrowInnerUp,"
    "BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,CheekSquintLeft,CheekSquintRight,"
    "NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,"
    "LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"
)
COLUMNS = HEADER.split(",")[2:]  # the 61 value columns
BLENDSHAPE_COLUMNS = COLUMNS[:52]
ANGLE_UNIT_DEG = 90.0
EYE_LOOK_MAX_DEG = 30.0
# (eye (0 right, 1 left), angle (0 yaw, 1 pitch)) -> its value column.
_EYE_COLUMNS = {(e, a): COLUMNS.index(f"{side}Eye{angle}")
                for e, side in enumerate(("Right", "Left")) for a, angle in enumerate(("Yaw", "Pitch"))}


def _scores(track_or_blendshapes, animation) -> tuple[np.ndarray, list[str]]:
    """(F, S) MediaPipe scores and their names from a Track, a (scores, names) pair, or
    (None) the animation's own copy."""
    src = track_or_blendshapes
    if src is None:
        return np.asarray(animation.mediapipe_blendshapes, np.float32), list(animation.mediapipe_blendshape_names)
    if hasattr(src, "blendshapes") and hasattr(src, "blendshape_names"):
        return np.asarray(src.blendshapes, np.float32), list(src.blendshape_names)
    scores, names = src
    return np.asarray(scores, np.float32), list(names)


def head_angles(head_pose: np.ndarray) -> np.ndarray:
    """(F, 4, 4) head -> camera transforms -> (F, 3) yaw, pitch, roll in radians for
    R = Ry(yaw) Rx(pitch) Rz(roll) (rotation part orthonormalized first)."""
    r = rotation_part(head_pose)
    yaw = np.arctan2(r[:, 0, 2], r[:, 2, 2])
    pitch = np.arcsin(np.clip(-r[:, 1, 2], -1.0, 1.0))
    roll = np.arctan2(r[:, 1, 0], r[:, 1, 1])
    return np.stack([yaw, pitch, roll], 1)


def timecodes(times: np.ndarray, fps: float) -> list[str]:
    """``HH:MM:SS:FF.fff`` for each time (seconds, clip presentation time; negative
    times are shifted to start at 0), frames counted at round(fps)."""
    rate = max(int(round(fps)), 1) if fps and np.isfinite(fps) else 30
    t = np.asarray(times, np.float64)
    t = t - min(float(t[0]), 0.0) if len(t) else t  # never negative
    frames = t * rate
    whole = np.floor(frames + 1e-6)
    frac = np.clip(frames - whole, 0.0, 0.999)
    whole = whole.astype(np.int64)
    ff = whole % rate
    secs = whole // rate
    return [f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}:{f:02d}.{int(round(x * 1000)) if x < 0.9995 else 999:03d}"
            for s, f, x in zip(secs.tolist(), ff.tolist(), frac.tolist())]


def _arkit(animation, track_or_blendshapes, scores, names) -> tuple[np.ndarray, list[str]]:
    """(F, A) ARKit curves and their names: the animation's, else computed from a Track,
    else (an old animation file and no Track) MediaPipe's raw scores."""
    if getattr(animation, "arkit_weights", None) is not None:
        return np.asarray(animation.arkit_weights, np.float64), list(animation.arkit_names)
    if hasattr(track_or_blendshapes, "landmarks_head"):
        return arkit_curves(track_or_blendshapes).astype(np.float64), list(track_or_blendshapes.blendshape_names)
    return scores.astype(np.float64), names


def livelink_values(animation, track_or_blendshapes=None) -> np.ndarray:
    """(F, 61) values in the column order of ``COLUMNS``."""
    F = animation.n_frames
    scores, names = _scores(track_or_blendshapes, animation)
    if len(scores) != F:
        raise CaptureError(f"Live Link export: {len(scores)} blendshape frames for {F} animation frames")
    curves, curve_names = _arkit(animation, track_or_blendshapes, scores, names)
    if len(curves) != F:
        raise CaptureError(f"Live Link export: {len(curves)} ARKit curve frames for {F} animation frames")
    arkit = {n.lower(): i for i, n in enumerate(curve_names) if n != "_neutral"}
    mp = {n.lower(): i for i, n in enumerate(names) if n != "_neutral"}
    out = np.zeros((F, len(COLUMNS)), np.float64)
    for c, col in enumerate(BLENDSHAPE_COLUMNS):
        if col.lower() in arkit:
            out[:, c] = curves[:, arkit[col.lower()]]
    out[:, :52] = np.clip(np.nan_to_num(out[:, :52]), 0.0, 1.0)

    unit = np.radians(ANGLE_UNIT_DEG)
    out[:, 52:55] = head_angles(animation.head_pose) / unit

    def s(name):
        i = mp.get(name.lower())
        return scores[:, i].astype(np.float64) if i is not None else np.zeros(F)

    gaze = getattr(animation, "eye_rotation", None)
    if gaze is not None:
        gaze = np.asarray(gaze, np.float64) / ANGLE_UNIT_DEG  # (F, 2 eyes (right, left), 2)
        for (e, a), col in _EYE_COLUMNS.items():
            out[:, col] = gaze[:, e, a]
    else:
        eye = EYE_LOOK_MAX_DEG / ANGLE_UNIT_DEG
        for (e, a), col in _EYE_COLUMNS.items():
            plus, minus = GAZE_SCORES[e, a]
            out[:, col] = (s(plus) - s(minus)) * eye
    out[:, 52:] = np.clip(np.nan_to_num(out[:, 52:]), -1.0, 1.0)
    return out


def write_livelink_csv(animation, track_or_blendshapes, path: str | os.PathLike) -> None:
    """Write ``animation`` as a Live Link Face CSV (atomic). ``track_or_blendshapes``: the
    clip's :class:`~capture2face.tracking.track.Track`, a ``(scores (F, S), names)`` pair,
    or None to use the animation's copy of MediaPipe's scores (for the eye angles, and the
    blendshapes of an animation saved without ARKit curves)."""
    values = livelink_values(animation, track_or_blendshapes)
    codes = timecodes(animation.times, animation.fps)
    prefix = f",{len(COLUMNS)},"
    # Formatted a block of rows at a time: the text of a long clip never sits in RAM whole.
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(HEADER + "\n")
        for s in range(0, len(codes), 2048):
            buf = io.StringIO()
            np.savetxt(buf, values[s:s + 2048].reshape(-1, len(COLUMNS)), fmt="%.6f", delimiter=",")
            fh.write("".join(c + prefix + r + "\n" for c, r in zip(codes[s:s + 2048], buf.getvalue().splitlines())))

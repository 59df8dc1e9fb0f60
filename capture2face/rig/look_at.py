"""A lookAt-by-expression character's look presets from the actor's gaze angle.

A VRM whose gaze turns its ``LookUp`` / ``LookDown`` / ``LookLeft`` / ``LookRight``
expressions (VRM 0.x ``lookAtTypeName`` "BlendShape", VRM 1.0 ``lookAt.type``
"expression") says how far each turns at each gaze angle (its range tables,
``FaceRig.look_ranges``, read by :func:`capture2face.gltf.vrm.look_ranges`). As three-vrm
and UniVRM do, the gaze's yaw turns LookLeft (yaw > 0, towards the character's own left)
or LookRight, its pitch LookDown (pitch > 0) or LookUp, each through its table; the two
eyes' mean angles, as those players take one gaze per head.
"""

from __future__ import annotations

import numpy as np

LOOK_PRESETS = ("lookleft", "lookright", "lookdown", "lookup")


def look_weights(weights: np.ndarray, morph_names: list[str], look_ranges: np.ndarray | None,
                 eye_rotation: np.ndarray | None) -> np.ndarray:
    """(F, M) ``weights`` with the look presets' columns set from the gaze (the module
    docs); unchanged where the rig has no range tables, no look preset or the track no gaze.

    Args:
        look_ranges: (3, D) preset weights of a horizontal, downward and upward gaze of
            0, 1, ..., D - 1 degrees.
        eye_rotation: (F, 2, 2) yaw, pitch in degrees per eye (``Animation.eye_rotation``).
    """
    if look_ranges is None or eye_rotation is None:
        return weights
    columns = {str(n).lower(): m for m, n in enumerate(morph_names)}
    if not any(p in columns for p in LOOK_PRESETS):
        return weights
    angles = np.asarray(eye_rotation, np.float64).mean(1)  # (F, 2) yaw, pitch
    yaw, pitch = angles[:, 0], angles[:, 1]
    degrees = np.arange(look_ranges.shape[1], dtype=np.float64)
    table = np.asarray(look_ranges, np.float64)
    look = {"lookleft": np.interp(np.maximum(yaw, 0.0), degrees, table[0]),
            "lookright": np.interp(np.maximum(-yaw, 0.0), degrees, table[0]),
            "lookdown": np.interp(np.maximum(pitch, 0.0), degrees, table[1]),
            "lookup": np.interp(np.maximum(-pitch, 0.0), degrees, table[2])}
    out = np.array(weights, np.float32, copy=True)
    for name, value in look.items():
        if name in columns:
            out[:, columns[name]] = value
    return out

"""ARKit blendshape names as characters spell them, and how a character is driven.

Character tools name the 52 ARKit morphs in their own ways: ``eyeBlinkLeft`` (ARKit,
Ready Player Me), ``EyeBlinkLeft`` (Live Link), ``eyeBlink_L`` (Face Cap),
``eyeBlink.L`` (Blender), ``blendShape1.eyeBlinkLeft`` (Maya's blendShape node) or
``head:eyeBlink_L`` (a namespace). :func:`canonical_arkit` maps each to ARKit's spelling
(MediaPipe's, the spelling of ``Animation.arkit_names``), or None for other names.

:func:`drive_mode` says how the retargeting drives a rig: ``"bones"`` (Dutreve's
feature-point path: landmark vertices or face bones tied to tracker landmarks) or
``"arkit"`` (no face bones: the clip's ARKit curves drive every morph of that name, or,
without ARKit names, the visemes and presets of :mod:`capture2face.rig.morph_conventions`).
"""

from __future__ import annotations

import re

import numpy as np

from capture2face.errors import CaptureError
from capture2face.rig.feature_points import AUTO_PREFIX, feature_correspondence
from capture2face.rig.morph_conventions import convention_morphs, convention_weights
from capture2face.topology import ARKIT_NAMES  # Apple's 52 (re-exported: rig.arkit_names.ARKIT_NAMES)

_BY_KEY = {n.lower(): n for n in ARKIT_NAMES}
#: (eye, angle) -> the eyeLook scores (plus, minus) whose difference follows that gaze
#: angle; eye 0 right, 1 left; angle 0 yaw (> 0 towards +x, the subject's left), 1 pitch
#: (> 0 down): ``Animation.eye_rotation``'s convention. Used by the Live Link export's
#: fallback and by the fidelity gaze checks.
GAZE_SCORES: dict[tuple[int, int], tuple[str, str]] = {
    (0, 0): ("eyeLookInRight", "eyeLookOutRight"),  # the right eye looks in towards +x
    (1, 0): ("eyeLookOutLeft", "eyeLookInLeft"),
    (0, 1): ("eyeLookDownRight", "eyeLookUpRight"),
    (1, 1): ("eyeLookDownLeft", "eyeLookUpLeft"),
}
# Bone names of automatic feature points (capture2face.character.auto_wrinkles): never a user's joint.
_SIDES = {"l": "left", "r": "right", "left": "left", "right": "right"}
# Separators of namespaces and node prefixes: "blendShape1.jawOpen", "head:jawOpen", "a|b".
_PREFIX = re.compile(r"[.:|]")
_SIDE_SUFFIX = re.compile(r"^(.*?)[ _.\-]?(l|r|left|right)$", re.IGNORECASE)
_WORD = re.compile(r"[ _\-]")


def canonical_arkit(name: str) -> str | None:
    """ARKit's spelling of a morph name, or None when it is not an ARKit blendshape.

    Case is ignored; ``Left``/``Right``, ``_L``/``_R``, ``.L``/``.R`` (and ``-``, space)
    mark the side; anything up to the last ``.``, ``:`` or ``|`` (other than a side
    suffix) is a prefix; ``_`` between words is ignored (``Mouth_Smile_L``).
    """
    text = str(name).strip()
    parts = _PREFIX.split(text)
    if len(parts) >= 2 and parts[-1].lower() in _SIDES:  # "eyeBlink.L": the side, not a prefix
        base, side = parts[-2], _SIDES[parts[-1].lower()]
    else:
        base, side = parts[-1], ""
    key = _WORD.sub("", base).lower()
    if not side and key in _BY_KEY:  # "mouthLeft" is a name of its own, not "mouth" + side
        return _BY_KEY[key]
    if not side:
        m = _SIDE_SUFFIX.match(base)
        if m is None:
            return None
        base, side = m.group(1), _SIDES[m.group(2).lower()]
        key = _WORD.sub("", base).lower()
    return _BY_KEY.get(key + side)


def arkit_morphs(morph_names: list[str]) -> dict[int, str]:
    """{morph index: ARKit name} of every morph whose name is an ARKit blendshape's."""
    out = {}
    for i, n in enumerate(morph_names):
        a = canonical_arkit(n)
        if a is not None:
            out[i] = a
    return out


def driven_morphs(morph_names: list[str]) -> dict[int, str]:
    """{morph index: name} of the morphs the ARKit curves drive: the ARKit-named ones, or,
    where a character has none, those another convention names
    (:mod:`capture2face.rig.morph_conventions`: visemes, VRM presets, Rocketbox)."""
    named = arkit_morphs(morph_names)
    if named:
        return named
    return {m: name for m, (_, name) in convention_morphs(morph_names).items()}


#: ``FaceRig.landmark_source`` of landmarks placed from what the head's own morphs move
#: (:data:`capture2face.character.landmark_sources.MORPHS`: anime faces the tracker cannot read).
MORPH_PLACED = "morphs"


def solved_morphs(rig) -> dict[int, str]:
    """:func:`driven_morphs` of ``rig`` that its landmarks may solve
    (:mod:`capture2face.retarget.arkit_solve`): the ARKit-named ones; another convention's
    where the tracker read the head's landmarks. Landmarks placed from the morphs say where
    they move, not where a human's features are: solved from them, Godette's lids followed
    the actor at 0.33-0.62 where its recipes alone give 0.59-1.06 (docs/characters.md)."""
    named = arkit_morphs(rig.morph_names)
    if named or getattr(rig, "landmark_source", "") == MORPH_PLACED:
        return named
    return driven_morphs(rig.morph_names)

def has_face_bones(rig) -> bool:
    """True when Dutreve's feature-point retargeting can drive ``rig`` (landmark vertices
    on its skin, or at least 4 bones tied to tracker landmarks)."""
    try:
        feature_correspondence(rig)
    except CaptureError:
        return False
    return True


def is_automatic(rig) -> bool:
    """True when the rig's face bones are automatic feature points
    (:mod:`capture2face.character.auto_wrinkles`), which only measure wrinkle influences."""
    return any(n.startswith(AUTO_PREFIX) for n in rig.bone_names)


def drive_mode(rig) -> str:
    """``"bones"`` (face bones: the Dutreve path, morphs solved or scored with it) or
    ``"arkit"`` (ARKit-named morphs and no face bones of its own: the ARKit curves drive
    them; automatic feature points and landmarks, if any, only measure).

    Raises:
        CaptureError: neither; the message says what is missing.
    """
    # Landmarks found automatically (FaceRig.landmark_source) only measure: the curves drive.
    if (is_automatic(rig) or getattr(rig, "landmark_source", "")) and driven_morphs(rig.morph_names):
        return "arkit"
    if has_face_bones(rig):
        return "bones"
    if driven_morphs(rig.morph_names):
        return "arkit"
    names = ", ".join(rig.morph_names[:4]) + (", ..." if rig.n_morphs > 4 else "")
    have = (f"its {rig.n_morphs} morph targets ({names}) have no ARKit names" if rig.n_morphs
            else "it has no morph targets")
    raise CaptureError(f"character '{rig.name}' cannot be driven: {have} and no face bones are tied to tracker "
                       "landmarks (name morphs like jawOpen / eyeBlink_L, or map them in a mapping JSON)")


def arkit_weights(arkit_names: list[str], arkit_curves: np.ndarray, morph_names: list[str]) -> np.ndarray:
    """(F, M) float32 morph weights: each ARKit-named morph takes its curve, others 0; a
    character without ARKit names: its visemes, VRM presets, ... from the curves
    (:func:`~capture2face.rig.morph_conventions.convention_weights`).

    Args:
        arkit_names: S curve names (``Animation.arkit_names``).
        arkit_curves: (F, S) curves in [0, 1] with ARKit meaning.
        morph_names: M morph names of the character (any spelling).
    """
    curves = np.asarray(arkit_curves, np.float32)
    if not arkit_morphs(morph_names):
        return convention_weights(arkit_names, curves, morph_names)
    index = {n: i for i, n in enumerate(arkit_names)}
    out = np.zeros((len(curves), len(morph_names)), np.float32)
    for m, name in arkit_morphs(morph_names).items():
        if name in index:
            out[:, m] = curves[:, index[name]]
    return np.clip(out, 0.0, 1.0)

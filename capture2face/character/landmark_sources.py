"""A user's character's tracker landmarks, found whichever way its face allows, before and
apart from its automatic wrinkles (a head whose wrinkle bake fails keeps them).

In turn: its front view read by the clips' tracker (:mod:`.landmarks`: realistic heads);
else what its own morphs move (:mod:`.morph_landmarks`: anime, stylised, low-poly faces the
tracker cannot read); else none. ``FaceRig.landmark_source`` says which, and report.json
repeats it (``character_landmarks``).
"""

from __future__ import annotations

import numpy as np

from capture2face.character.landmarks import SurfaceLandmarks, find_surface_landmarks
from capture2face.character.mirror_eyes import mirrored_eyes
from capture2face.character.morph_landmarks import morph_landmarks
from capture2face.errors import CaptureError
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.log import log

TRACKER, MORPHS, NONE = "tracker front view", "morphs", "none"


def with_landmarks(rig: FaceRig) -> FaceRig:
    """``rig`` with its landmarks cast (``landmark_faces``, ``landmark_bary``,
    ``landmark_vertices``) and ``landmark_source``; as it is, with source "none" and one
    warning, where neither way finds them."""
    reasons = []
    for source, find in ((TRACKER, find_surface_landmarks), (MORPHS, morph_landmarks)):
        try:
            found: SurfaceLandmarks = find(rig)
        except CaptureError as exc:
            reasons.append(str(exc).removeprefix(f"character '{rig.name}': "))
            continue
        if source == TRACKER:  # an eye cast off its lids takes the other's mirror image
            found = SurfaceLandmarks(*mirrored_eyes(rig, found.faces, found.bary, found.vertices))
        else:
            log.info("character '%s': %s; its landmarks are placed from what its morphs move", rig.name, reasons[0])
        return rig.replace(landmark_faces=found.faces, landmark_bary=found.bary, landmark_vertices=found.vertices,
                           landmark_source=source)
    log.warning("character '%s': no landmarks found (%s): no landmark fidelity figures, wrinkles or eye centres "
                "from them", rig.name, "; ".join(reasons))
    return rig.replace(landmark_source=NONE)


def landmark_facts(rig: FaceRig) -> dict:
    """report.json's ``character_landmarks``: how the landmarks were found and how many
    have a place on the character."""
    return {"source": rig.landmark_source or "given", "found": int((np.asarray(rig.landmark_vertices) >= 0).sum())}


_LOOKS = ("eyelook", "lookup", "lookdown", "lookleft", "lookright")  # ARKit's and VRM's look morphs


def eye_facts(rig: FaceRig) -> dict:
    """report.json's ``character_eyes``: how its eyes follow the actor's gaze. ``turn``:
    "eyeballs" (they turn about ``eye_centres``; ``centres`` says how those were found:
    ``FaceRig.eye_source``, "given" for the built-in avatars and our own exports),
    "morphs" (its look morphs, ``morphs``: ARKit ``eyeLook*``, VRM ``LookUp`` ...), or
    "none"."""
    if rig.has_eyes:
        return {"turn": "eyeballs", "centres": rig.eye_source or "given"}
    looks = [n for n in rig.morph_names if n.lower().replace("_", "").startswith(_LOOKS)]
    return {"turn": "morphs" if looks else "none", "centres": "none", "morphs": looks}

"""Figures for faces the tracker cannot read back (anime, stylised): the character's own
landmarks posed by the animation, compared with the actor's track.

``eval shading`` tracks the rendered video back; the tracker cannot read an anime render,
so on such heads its figures measure the tracker's guesses. Here the character's landmark
points (``FaceRig.landmark_vertices`` / ``landmark_faces``, found from its morphs where the
tracker cannot read it) are deformed frame by frame by the animation's morph weights and
bones (:func:`~capture2face.measures.character_measures`: head coordinates, the head's
rotation left out as the tracked-back figures leave it out), low-passed as the actor's
measures are, and compared with the actor's by the same :func:`~.shading.feature_follow`:
``mouth_open``, ``brows``, ``eyes`` r and gain (the character's standard deviation over the
actor's, both in inter-ocular distances; eyes in rest openings).

An anime mouth or brow may be drawn small: its morphs at 1 move its landmarks less than a
human's do, and its gain in inter-ocular distances stays low however fully it is driven
(Godette's widest mouth opens 0.08 inter-ocular distances, the built-in avatar's 0.21).
``<feature>_range_gain`` is the gain with such a character's measure stretched by the
built-in avatar's range over its own (a range is the most any one of the morphs at 1
moves the measure; ``<feature>_range``: the character's over the avatar's): the share of
its own range it uses against the share a human face uses. A character whose range is
the avatar's or larger (the built-in avatar, ICT, Ready Player Me) is not stretched: its
``range_gain`` is its gain. A feature none of its morphs moves has no figures (NaN) and
``<feature>_range`` 0.
"""

from __future__ import annotations

import numpy as np

from capture2face.eval.shading import FEATURES, feature_follow
from capture2face.measures import character_measures, character_rest_measures, lowpass, source_measures
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig

MEASURE = "posed landmarks"  # the JSON's "measured_by" of these figures


def measure_ranges(rig: FaceRig) -> np.ndarray:
    """(6,) the most any one of the rig's morphs at 1 (bones at rest) changes each
    measure (:data:`~capture2face.measures.MEASURES`) from its rest."""
    if not rig.n_morphs:
        return np.zeros(6)
    bones = np.broadcast_to(rig.bone_rest[None], (rig.n_morphs,) + rig.bone_rest.shape)
    moved = character_measures(rig, bones, np.eye(rig.n_morphs, dtype=np.float32)) - character_rest_measures(rig)
    return np.abs(moved).max(0)


def posed_follow(track, animation, rig: FaceRig) -> dict:
    """The posed-landmark figures of one retargeted clip (the module docs): ``measured_by``,
    ``<feature>_r``, ``_gain``, ``_range_gain`` and ``_range`` (in the built-in avatar's
    ranges) of each of :data:`~.shading.FEATURES`."""
    keep = np.asarray(track.presence, bool)
    actor = source_measures(track)[keep]
    posed = lowpass(character_measures(rig, animation.bone_positions, animation.blend_weights), track.fps)[keep]
    out: dict = {"measured_by": MEASURE, **feature_follow(actor, posed)}
    ranges, reference = measure_ranges(rig), measure_ranges(default_avatar())
    scale = np.maximum(1.0, np.divide(reference, ranges, out=np.full(len(ranges), np.nan), where=ranges > 1e-6))
    scaled = feature_follow(actor, posed * scale)
    for name, cols in FEATURES.items():
        out[f"{name}_range_gain"] = scaled[f"{name}_gain"]
        out[f"{name}_range"] = float(np.mean(ranges[cols] / reference[cols]))
        if not np.all(ranges[cols] > 1e-6):  # nothing moves it: no figures
            out[f"{name}_r"] = out[f"{name}_gain"] = out[f"{name}_range_gain"] = float("nan")
    return out

"""The face read with its hair hidden: a check render of ``eval characters``.

The tracker reads a character's face from avatar.mp4 as it reads an actor's. Where the
character's hair covers its brows (a Ready Player Me fringe), the tracker puts its brow
points on the skin below them, and the brows' figure tracked back says how the hair looks,
not how the brows move (docs/characters.md). The check renders the same performance with
the character's overlays left out (``FaceRig.overlay_vertices``: what its file draws in
front of the face and landmarks must not land on, hair and lash cards, beards, glasses) and
tracks that video back the same way. Every character gets it alike, next to the figures of
avatar.mp4 as it is; one without overlays (the built-in avatar, whose head shell is its
own) gets the same render's figures.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from capture2face.eval import shading
from capture2face.pipeline import RenderPass
from capture2face.rig.face_rig import FaceRig

#: The run folder's subfolder the check renders into.
FOLDER = "hair_hidden"


def hair_hidden(rig: FaceRig) -> FaceRig | None:
    """``rig`` without the triangles of its overlays (a triangle's is its last vertex's, as
    its material), or None where it has none."""
    if rig.overlay_vertices is None:
        return None
    triangles = np.asarray(rig.triangles)
    hair = np.asarray(rig.overlay_vertices, bool)[triangles[:, -1]]
    if not hair.any():
        return None
    return dataclasses.replace(rig, triangles=triangles[~hair])


def hair_hidden_figures(clip, track, animation, rig: FaceRig, run_dir: Path, options, shown: dict,
                        progress: bool = False) -> dict:
    """The tracked-back figures (:func:`~capture2face.eval.shading.shading_of`) of the
    performance rendered without the rig's overlays into ``run_dir/hair_hidden``; ``shown``:
    avatar.mp4's own, returned (with ``"hidden_triangles": 0``) for a rig without them."""
    bare = hair_hidden(rig)
    if bare is None:
        return {**shown, "hidden_triangles": 0}
    folder = Path(run_dir) / FOLDER
    folder.mkdir(parents=True, exist_ok=True)
    RenderPass(clip, track, animation, bare, folder, options).run(progress)
    track.save(folder / "track.npz")
    return {**shading.shading_of(folder, progress=progress),
            "hidden_triangles": int(len(rig.triangles) - len(bare.triangles))}

"""capture2face: a recorded face video drives a skinned character with automatic wrinkles.

The stages are plain functions over dataclasses of NumPy arrays::

    from capture2face import run, track_clip, default_avatar, FaceRig, Track, Animation
    from capture2face.retarget import retarget   # the subpackage shares the function's name

Names are imported lazily so that ``import capture2face`` stays fast and a notebook
only pays for the stages it uses.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_API = {
    "CaptureError": "capture2face.errors",
    "FaceRig": "capture2face.rig.face_rig",
    "default_avatar": "capture2face.rig.avatar",
    "deform": "capture2face.rig.deform",
    "export_glb": "capture2face.gltf",
    "import_glb": "capture2face.character.load",
    "Track": "capture2face.tracking.track",
    "TrackOptions": "capture2face.tracking",
    "track_clip": "capture2face.tracking",
    "Animation": "capture2face.retarget.animation",
    "RetargetOptions": "capture2face.retarget",
    "Renderer": "capture2face.render",
    "RenderOptions": "capture2face.render",
    "SynthOptions": "capture2face.synth",
    "synthesize": "capture2face.synth",
    "RunOptions": "capture2face.pipeline",
    "run": "capture2face.pipeline",
}

__all__ = sorted(_API) + ["__version__"]


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'capture2face' has no attribute {name!r}")

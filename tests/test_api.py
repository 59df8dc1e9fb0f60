"""The package's top-level API resolves to the stage functions, lazily."""

import subprocess
import sys

import capture2face

# Each top-level name -> the stage (sub)package that owns it, by its stable path.
API = {
    "CaptureError": "capture2face.errors",
    "FaceRig": "capture2face.rig.face_rig",
    "default_avatar": "capture2face.rig.avatar",
    "deform": "capture2face.rig.deform",
    "export_glb": "capture2face.gltf",
    "import_glb": "capture2face.gltf",
    "Track": "capture2face.tracking",
    "TrackOptions": "capture2face.tracking",
    "track_clip": "capture2face.tracking",
    "Animation": "capture2face.retarget",
    "RetargetOptions": "capture2face.retarget",
    "Renderer": "capture2face.render",
    "RenderOptions": "capture2face.render",
    "SynthOptions": "capture2face.synth",
    "synthesize": "capture2face.synth",
    "RunOptions": "capture2face.pipeline",
    "run": "capture2face.pipeline",
}
CLASSES = {"CaptureError", "FaceRig", "Track", "TrackOptions", "Animation", "RetargetOptions", "Renderer",
           "RenderOptions", "SynthOptions", "RunOptions"}


def test_top_level_names_resolve_to_their_stage_objects():
    """Each name is the very object its stage exports (identity, not a copy or a wrapper),
    named as it is, and __all__ lists exactly the API."""
    import importlib
    import inspect

    assert sorted(capture2face.__all__) == sorted([*API, "__version__"])
    for name, module in API.items():
        obj = getattr(capture2face, name)
        assert obj is getattr(importlib.import_module(module), name), name
        assert obj.__name__ == name, name  # not another object under this name
        assert inspect.isclass(obj) == (name in CLASSES), name
        stage = ".".join(module.split(".")[:2])  # capture2face.rig, capture2face.tracking, ...
        assert obj.__module__ == stage or obj.__module__.startswith(stage + "."), name
    assert issubclass(capture2face.CaptureError, Exception)
    assert capture2face.run is importlib.import_module("capture2face.pipeline").run
    assert isinstance(capture2face.__version__, str)


def test_import_is_lazy():
    # A notebook that imports the package pays for no stage it does not use.
    code = "import sys, capture2face; print(any(m.startswith(('mediapipe', 'moderngl')) for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

"""The package's top-level API resolves to the stage functions, lazily."""

import re
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
    "import_glb": "capture2face.character.load",
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


# ---- options compose their stages' options (issue 30); the old flat names still work ----
def test_old_run_keywords_warn_and_give_the_same_options():
    import pickle

    import pytest

    from capture2face.pipeline import RunOptions, options_json
    from capture2face.render import RenderOptions
    from capture2face.tracking import TrackOptions
    from capture2face.tracking.landmarker import LandmarkerOptions

    new = RunOptions(character="wide", compare=False,
                     render=RenderOptions(size=256, wrinkles="zones"),
                     track=TrackOptions(landmarker=LandmarkerOptions(face_model="m.task", faces="center", face=1),
                                        neutral_frame=3, workers=2))
    old_keywords = {"size": 256, "wrinkles": "zones", "face_model": "m.task", "faces": "center", "face": 1,
                        "neutral_frame": 3, "track_workers": 2}
    places = {"size": "render=RenderOptions(size=", "face": "track=TrackOptions(landmarker=LandmarkerOptions(face=",
              "track_workers": "track=TrackOptions(workers=", "neutral_frame": "track=TrackOptions(neutral_frame="}
    for name, place in places.items():
        with pytest.warns(DeprecationWarning, match=re.escape(f"RunOptions({place}")):
            RunOptions(**{name: old_keywords[name]})
    with pytest.warns(DeprecationWarning):
        old = RunOptions(character="wide", compare=False, **old_keywords)
    assert old == new and options_json(old) == options_json(new)
    with pytest.warns(DeprecationWarning, match=re.escape("RunOptions.size is deprecated; use RunOptions.render.size")):
        assert old.size == 256
    with pytest.warns(DeprecationWarning):
        assert (old.face, old.track_workers, old.neutral_frame) == (1, 2, 3)
    with pytest.warns(DeprecationWarning):
        old.size = 128
    assert old.render.size == 128 and new.render.size == 256  # parts are copied, never shared and changed
    assert pickle.loads(pickle.dumps(new)) == new  # Ray ships them to its workers


def test_old_track_keywords_warn_and_give_the_same_options():
    import pytest

    from capture2face.tracking import TrackOptions
    from capture2face.tracking.landmarker import LandmarkerOptions

    landmarker = LandmarkerOptions(num_faces=2, face=1, min_tracking_confidence=0.3)
    with pytest.warns(DeprecationWarning) as seen:
        old = TrackOptions(num_faces=2, face=1, min_tracking_confidence=0.3, max_frames=5)
    assert "TrackOptions(num_faces=...) is deprecated; use TrackOptions(landmarker=LandmarkerOptions(num_faces=...))" \
        in [str(w.message) for w in seen]
    assert old == TrackOptions(landmarker=landmarker, max_frames=5)
    with pytest.warns(DeprecationWarning):
        assert old.num_faces == 2 and old.landmarker_options() == landmarker
    with pytest.warns(DeprecationWarning):  # a flat keyword applies over the landmarker given beside it
        both = TrackOptions(landmarker=landmarker, face=0)
    assert both.landmarker.face == 0 and landmarker.face == 1 and both.landmarker.num_faces == 2
    with pytest.raises(TypeError):
        TrackOptions("model.task")  # keywords only: an old positional call fails, never lands elsewhere


def test_report_options_keep_their_keys():
    """report.json's "options" (and batch --resume's comparison) keep the flat names and
    values of before; a stage's other settings appear only when changed."""
    from capture2face.pipeline import RunOptions, options_json
    from capture2face.retarget import RetargetOptions
    from capture2face.tracking import TrackOptions

    assert options_json(RunOptions()) == {
        "character": None, "wrinkles": "auto", "size": 512, "neutral_frame": None, "neutral_image": None,
        "neutral_clip": None, "face_model": None, "compare": True, "samples": None, "crf": 20, "preset": "veryfast",
        "queue_frames": 8, "allow_truncated": False, "audio": True, "faces": "largest", "face": None,
        "track_workers": None}
    changed = options_json(RunOptions(retarget=RetargetOptions(depth_motion=1.0), track=TrackOptions(max_frames=9)))
    assert changed["retarget"] == {"depth_motion": 1.0} and changed["track"] == {"max_frames": 9}
    assert "render" not in changed


def test_deprecated_names_unused_in_the_package():
    """Nothing in capture2face reads or passes the old flat names (its users see no warning)."""
    import warnings

    from capture2face.pipeline import RunOptions, run_render_options

    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        options = RunOptions()
        options.validate()
        run_render_options(options)

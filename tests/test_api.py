"""The package's top-level API resolves to the stage functions, lazily."""

import subprocess
import sys

import capture2face


def test_top_level_names_resolve_to_their_stage_objects():
    from capture2face.pipeline import run
    from capture2face.rig.face_rig import FaceRig
    from capture2face.tracking import track_clip

    assert capture2face.run is run
    assert capture2face.track_clip is track_clip
    assert capture2face.FaceRig is FaceRig
    for name in capture2face.__all__:
        assert getattr(capture2face, name) is not None, name


def test_import_is_lazy():
    # A notebook that imports the package pays for no stage it does not use.
    code = "import sys, capture2face; print(any(m.startswith(('mediapipe', 'moderngl')) for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

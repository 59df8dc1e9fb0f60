"""Shared pytest fixtures (plain helpers live in tests/helpers.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests import helpers


@pytest.fixture(scope="session")
def avatar():
    """The built-in default avatar (a ``FaceRig``), built or read from the disk cache once."""
    from capture2face import default_avatar

    return default_avatar()


@pytest.fixture(scope="session")
def wide():
    """The built-in avatar's 'wide' variant (another face shape, same topology)."""
    from capture2face import default_avatar

    return default_avatar(variant="wide")


@pytest.fixture(scope="session")
def sample_clip(tmp_path_factory) -> Path:
    """A short synthetic performance (90 frames, 256 px, 30 fps) made by ``synthesize``,
    with head motion and expressions: the pipeline's test clip."""
    from capture2face.synth import SynthOptions, synthesize

    path = tmp_path_factory.mktemp("sample") / "synth_clip.mp4"
    synthesize(path, SynthOptions(frames=90, size=256, seed=2), progress=False)
    return path


@pytest.fixture(scope="session")
def synthetic_clip(tmp_path_factory):
    """A synthetic performance at tracking resolution (60 frames, 512 px, 30 fps, seed 0)
    through neutral and both reference poses: a ``SyntheticClip`` (video_path,
    truth_path, truth) for tests that compare against ground truth."""
    from capture2face.synth import SynthOptions, synthesize

    path = tmp_path_factory.mktemp("synthetic") / "clip.mp4"
    return synthesize(path, SynthOptions(frames=60, size=512, seed=0), progress=False)


@pytest.fixture(scope="session")
def hero(tmp_path_factory) -> Path:
    """An ARKit character: the default avatar exported with ARKit morph names."""
    from capture2face.gltf.arkit_export import export_arkit_character
    from capture2face.rig.avatar import default_avatar

    path = tmp_path_factory.mktemp("hero") / "hero.glb"
    export_arkit_character(default_avatar(), path)
    return path


@pytest.fixture
def no_tracking(monkeypatch):
    """Any call into the tracker (or past it) fails the test: the checks must come first."""
    import capture2face.eval.fidelity as eval_fidelity
    from capture2face import batch
    from capture2face.pipeline import runner, stages

    def tracked(*args, **kwargs):
        raise AssertionError("the clip was tracked before the failing check")

    monkeypatch.setattr(runner, "track_stage", tracked)
    monkeypatch.setattr(eval_fidelity, "track_stage", tracked)
    monkeypatch.setattr(stages, "track_clip", tracked)
    monkeypatch.setattr(batch, "_run_clip", tracked)


@pytest.fixture(scope="session")
def rom_take(tmp_path_factory) -> Path:
    """The range-of-motion protocol performed by ../shared/characters/ict-a.glb at 256 px
    (``synth --rom``, ~1260 frames; skipped without the shared characters)."""
    from capture2face.character.load import load_character
    from capture2face.synth import SynthOptions, synthesize

    actor = load_character(helpers.shared_character("ict-a.glb"))
    path = tmp_path_factory.mktemp("rom") / "rom.mp4"
    synthesize(path, SynthOptions(size=256, rom=True), progress=False, actor=actor)
    return path


@pytest.fixture(scope="session")
def actor_json(rom_take, tmp_path_factory) -> Path:
    """ict-a's actor.json, learned from :func:`rom_take` by ``capture2face calibrate``."""
    from capture2face.cli import main

    path = tmp_path_factory.mktemp("actor") / "actor.json"
    assert main(["-q", "calibrate", str(rom_take), "-o", str(path)]) == 0
    return path

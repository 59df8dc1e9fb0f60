"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_CLIPS = Path(__file__).resolve().parents[2] / "shared" / "clips"
SHARED_CHARACTERS = Path(__file__).resolve().parents[2] / "shared" / "characters"


def shared_clip(name: str) -> Path:
    """A real recorded clip from ../shared/clips; skips the test when it is absent."""
    path = SHARED_CLIPS / name
    if not path.is_file():
        pytest.skip(f"{path} not present (real clips live in ../shared/clips)")
    return path


def shared_character(name: str) -> Path:
    """A third-party head from ../shared/characters (ICT-FaceKit); skips the test when it
    is absent."""
    path = SHARED_CHARACTERS / name
    if not path.is_file():
        pytest.skip(f"{path} not present (third-party heads live in ../shared/characters)")
    return path


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


def truncated_copy(clip: Path, folder: Path) -> Path:
    """``clip`` remuxed with its index first (faststart), then cut at 60% of its bytes: a
    clip whose decoding fails part way, the way a download cut short does."""
    import av

    faststart = folder / "faststart.mp4"
    with av.open(str(clip)) as src, av.open(str(faststart), "w", options={"movflags": "faststart"}) as dst:
        stream = dst.add_stream_from_template(src.streams.video[0])
        for packet in src.demux(src.streams.video[0]):
            if packet.size:
                packet.stream = stream
                dst.mux(packet)
    data = faststart.read_bytes()
    cut = folder / "cut.mp4"
    cut.write_bytes(data[: len(data) * 6 // 10])
    return cut

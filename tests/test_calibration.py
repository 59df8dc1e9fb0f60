"""A rest from outside the clip (--neutral-image, --neutral-clip) and batch's rest takes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from capture2face.batch import BatchClip, clip_options, expand_inputs
from capture2face.errors import CaptureError
from capture2face.pipeline import RunOptions
from capture2face.pipeline.options import input_files
from capture2face.tracking import TrackOptions, track_clip
from capture2face.tracking.rest import GEOMETRY, actor_rest, rest_geometry
from tests.helpers import shared_clip

FRAMES = 60


def _still(clip, frame: int, path) -> None:
    import av
    import cv2

    with av.open(str(clip)) as c:
        for i, f in enumerate(c.decode(video=0)):
            if i == frame:
                cv2.imwrite(str(path), f.to_ndarray(format="rgb24")[:, :, ::-1])
                return


@pytest.fixture(scope="module")
def d11():
    clip = shared_clip("d11.mp4")
    return clip, track_clip(clip, TrackOptions(max_frames=FRAMES, workers=1), progress=False)


def test_neutral_image_rests_the_track_on_the_photo(d11, tmp_path):
    """A still of the clip's own calmest frame as the neutral image: the rest is that
    frame's face (brows, lids and lips within 0.01 IOD of the clip's own reading of it,
    after the photo is laid onto the clip's head coordinates), and says where it came from."""
    clip, own = d11
    frame = int(actor_rest(own).frames["face"][0])
    _still(clip, frame, tmp_path / "rest.jpg")
    track = track_clip(clip, TrackOptions(max_frames=FRAMES, workers=1, neutral_image=tmp_path / "rest.jpg"),
                       progress=False)
    rest = actor_rest(track)
    assert rest.source == f"image {tmp_path / 'rest.jpg'}"
    assert all(len(f) == 0 for f in rest.frames.values()) and rest.single_frame is None
    got = rest_geometry(rest.face[None])[0]
    want = rest_geometry(np.asarray(own.landmarks_head[frame:frame + 1]))[0]
    assert np.abs(got - want).max() < 0.01, dict(zip(GEOMETRY, got - want))
    np.testing.assert_array_equal(track.landmarks_head, own.landmarks_head)  # only the rest changed


def test_neutral_clip_gives_its_own_rest(d11):
    """The clip as its own neutral take: the same rest (brows, lids and lips within 0.005
    IOD), only laid onto the 60 tracked frames' median face."""
    clip, own = d11
    cut = dataclasses.replace(TrackOptions(max_frames=FRAMES, workers=1), neutral_clip=clip)
    rest = actor_rest(track_clip(clip, cut, progress=False))
    whole = actor_rest(track_clip(clip, TrackOptions(workers=1), progress=False))  # the take is not cut
    assert rest.source == f"clip {clip}"
    got, want = rest_geometry(rest.face[None])[0], rest_geometry(whole.face[None])[0]
    assert np.abs(got - want).max() < 0.005, dict(zip(GEOMETRY, got - want))


def test_a_neutral_image_without_a_face_fails_in_one_line(d11, tmp_path):
    import cv2

    cv2.imwrite(str(tmp_path / "wall.jpg"), np.full((240, 320, 3), 128, np.uint8))
    with pytest.raises(CaptureError, match=r"^--neutral-image: .*wall\.jpg: no face"):
        track_clip(d11[0], TrackOptions(max_frames=5, workers=1, neutral_image=tmp_path / "wall.jpg"),
                   progress=False)


def test_one_rest_at_a_time_and_it_must_exist(tmp_path):
    with pytest.raises(CaptureError, match="--neutral-frame and --neutral-clip"):
        TrackOptions(neutral_frame=3, neutral_clip=__file__).validate()
    with pytest.raises(CaptureError, match="--neutral-image .*nope.jpg: no such file"):
        TrackOptions(neutral_image=tmp_path / "nope.jpg").validate()


def test_batch_finds_each_clips_rest_take(tmp_path):
    """Sidecars (CLIP.neutral.jpg / .mp4) and a list file's second column name each clip's
    rest take; a sidecar is never a clip of its own; the take becomes the clip's
    neutral_image or neutral_clip by its extension."""
    for name in ("a.mp4", "a.neutral.jpg", "b.mp4", "b.neutral.mp4", "c.mp4", "rest c.png"):
        (tmp_path / name).write_bytes(b"x")
    clips = {c.name: c for c in expand_inputs([tmp_path])}
    assert set(clips) == {"a", "b", "c"}
    assert clips["a"].neutral == str(tmp_path / "a.neutral.jpg")
    assert clips["b"].neutral == str(tmp_path / "b.neutral.mp4") and clips["c"].neutral is None
    listing = tmp_path / "takes.txt"
    listing.write_text("c.mp4\trest c.png\na.mp4 | b.neutral.mp4  # another take\nb.mp4\n")
    listed = {c.name: c for c in expand_inputs([listing])}
    assert listed["c"].neutral == str(tmp_path / "rest c.png")
    assert listed["a"].neutral == str(tmp_path / "b.neutral.mp4")  # the list wins over the sidecar
    assert listed["b"].neutral == str(tmp_path / "b.neutral.mp4")  # no column: the sidecar
    options = RunOptions()
    assert clip_options(clips["a"], options).track.neutral_image == str(tmp_path / "a.neutral.jpg")
    assert clip_options(clips["b"], options).track.neutral_clip == str(tmp_path / "b.neutral.mp4")
    assert clip_options(clips["c"], options) is options
    forced = RunOptions(track=TrackOptions(neutral_frame=4))  # the batch's own rest wins
    assert clip_options(BatchClip("x.mp4", "x", "x.neutral.jpg"), forced) is forced
    # The take is one of the run's inputs: --resume reruns a clip whose take changed.
    assert input_files(clips["a"].path, clip_options(clips["a"], options))["neutral_image"] == clips["a"].neutral

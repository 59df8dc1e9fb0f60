"""``eval shading``: the skin's darkening in a rendered video, sampled where the tracker sees
the cheeks and the chin."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from capture2face.errors import CaptureError
from capture2face.eval import shading
from capture2face.io.video_output import VideoWriter


def test_darkening_counts_dark_frames_only():
    b = np.full((100, 2), 100.0)
    b[:10, 0] = 80.0  # 10 % of frames 20 % darker: the 95th percentile sees them
    b[:10, 1] = 130.0  # brighter frames are not a shading fault
    np.testing.assert_allclose(shading.darkening(b), [0.2, 0.0], atol=1e-6)
    b[:3, 0] = 80.0
    b[3:10, 0] = 100.0  # 3 % of frames: below the 95th percentile
    np.testing.assert_allclose(shading.darkening(b)[0], 0.0, atol=1e-6)


def test_darkening_takes_out_the_light_that_follows_the_head():
    """A patch whose brightness follows the head's yaw (turned away from the light) and
    that also darkens by 15 % in 8 % of frames (a shading fault): with the rotations, only
    the fault is left; without them, the turn counts as darkening too."""
    from capture2face.maths.rotations import rotation_ypr

    rng = np.random.default_rng(0)
    n = 400
    yaw = 25.0 * np.sin(np.linspace(0, 6 * np.pi, n))
    rot = rotation_ypr(np.stack([yaw, rng.normal(0, 3, n), np.zeros(n)], 1))
    lit = 150.0 + 40.0 * rot[:, 0, 2]  # diffuse light: linear in the rotation
    fault = np.zeros(n)
    fault[rng.choice(n, 32, replace=False)] = 1.0
    b = np.stack([lit * (1.0 - 0.15 * fault), lit], 1)
    plain, turned = shading.darkening(b), shading.darkening(b, rot)
    assert turned[1] < 0.002 < 0.05 < plain[1]  # the turn alone: nothing left
    assert 0.12 < turned[0] < 0.18  # the fault is still seen


def test_patch_brightness_samples_each_disc_where_the_landmarks_are(tmp_path):
    """A video whose left half darkens over time, landmarks on both halves: the disc on the
    left follows it, the one on the right stays, frames without a face are NaN."""
    n, size = 12, (160, 120)
    levels = np.linspace(200, 100, n)
    video = tmp_path / "avatar.mp4"
    with VideoWriter(video, 30, size, crf=0) as out:
        for level in levels:
            frame = np.full((size[1], size[0], 3), 180, np.uint8)
            frame[:, :80] = int(level)
            out.write(frame)
    px = np.zeros((n, 478, 2))
    px[:, 33], px[:, 263] = (30, 40), (130, 40)  # IOD 100 px: discs of 8 px
    px[:, shading.PATCHES["cheek_right"]] = (40, 80)  # left half
    px[:, shading.PATCHES["cheek_left"]] = (120, 80)  # right half
    px[:, shading.PATCHES["chin"]] = (120, 100)
    presence = np.ones(n, bool)
    presence[5] = False
    track = SimpleNamespace(n_frames=n, presence=presence, landmarks_px=px)
    b = shading.patch_brightness(video, track)
    assert np.isnan(b[5]).all() and not np.isnan(np.delete(b, 5, 0)).any()
    got = np.delete(b[:, 0], 5)
    assert np.corrcoef(got, np.delete(levels, 5))[0, 1] > 0.99
    assert abs(got[0] - got[-1] - 100) < 6  # luminance of grey = its level (H.264 rounding)
    assert np.nanstd(b[:, 1]) < 1.5 and abs(np.nanmean(b[:, 1]) - 180) < 3


def test_a_beard_sliding_under_a_disc_is_no_darkening_in_the_flat_colour_video(tmp_path):
    """The tracked chin point slides over a goatee's edge (a dark block that covers part of
    the disc in a tenth of the frames): avatar.mp4 reads it as darkening, the same frames
    with the base colour flat (skin.mp4, where eval characters reads it) do not."""
    n, size = 60, (160, 120)
    px = np.zeros((n, 478, 2))
    px[:, 33], px[:, 263] = (30, 40), (130, 40)  # IOD 100 px: discs of 8 px
    for name, centre in zip(shading.PATCHES, ((40, 60), (120, 60), (80, 90))):
        px[:, shading.PATCHES[name]] = centre
    track = SimpleNamespace(n_frames=n, presence=np.ones(n, bool), landmarks_px=px)
    videos = {"avatar.mp4": True, "skin.mp4": False}
    for name, beard in videos.items():
        with VideoWriter(tmp_path / name, 30, size, crf=0) as out:
            for f in range(n):
                frame = np.full((size[1], size[0], 3), 170, np.uint8)
                if beard:
                    frame[94 - (f % 10 == 0) * 6:, :] = 50  # over the disc's lower edge; 6 px more now and then
                out.write(frame)
    rot = np.repeat(np.eye(3)[None], n, 0)
    chin = list(shading.PATCHES).index("chin")
    assert shading.read_darkening(tmp_path / "avatar.mp4", track, rot)[chin] > 0.1
    assert np.all(shading.read_darkening(tmp_path / "skin.mp4", track, rot) < 0.01)


def test_a_folder_without_avatar_video_is_refused(tmp_path):
    with pytest.raises(CaptureError, match="avatar.mp4 and track.npz"):
        shading.shading_of(tmp_path)


def test_darkest_frames_name_where_and_when_the_p95_comes_from():
    """Each disc names its darkest frames, darkest first, with their darkening; frames
    without a face (NaN) are never named; the p95 is among the named frames' values."""
    b = np.full((100, 3), 100.0)
    b[[40, 41, 42, 43, 44, 45, 46, 47, 48, 49], 0] = np.linspace(95, 86, 10)  # a smile: 5-14 % darker
    b[7, 1] = 90.0
    b[8, 1] = np.nan
    per_frame = shading.frame_darkening(b)
    got = shading.darkest_frames(per_frame, n=4)
    assert list(got) == list(shading.PATCHES)
    assert [f for f, _ in got["cheek_right"]] == [49, 48, 47, 46]
    np.testing.assert_allclose([d for _, d in got["cheek_right"]], [0.14, 0.13, 0.12, 0.11], atol=1e-4)
    assert got["cheek_left"][0] == [7, 0.1] and 8 not in [f for f, _ in got["cheek_left"]]
    p95 = shading.darkening(b)[0]
    assert got["cheek_right"][-1][1] <= p95 + 0.02 and np.isclose(p95, np.nanpercentile(per_frame[:, 0], 95))

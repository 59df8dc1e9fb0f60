"""The decoder every stage uses: timestamps, rotation, bad inputs (small files made here)."""

from __future__ import annotations

import logging
from fractions import Fraction

import av
import numpy as np
import pytest

from capture2face.errors import CaptureError
from capture2face.io.video_input import iter_frames, open_video, prefetch


def encode(path, frames, fps=30, pts=None, time_base=None, rotation=None, codec="libx264",
           faststart=False, pix_fmt="yuv420p"):
    """Write ``frames`` (list of (H, W, 3) uint8) with optional explicit pts and rotation."""
    opts = {"movflags": "faststart"} if faststart else {}
    with av.open(str(path), "w", options=opts) as c:
        s = c.add_stream(codec, rate=fps)
        s.height, s.width = frames[0].shape[:2]
        s.pix_fmt = pix_fmt
        if time_base is not None:  # the encoder would round pts to 1/fps otherwise
            s.time_base = time_base
            s.codec_context.time_base = time_base
        if rotation is not None:
            s.set_display_rotation(rotation)
        for i, img in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            if pts is not None:
                vf.pts = int(pts[i])
                vf.time_base = time_base
            for p in s.encode(vf):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def noise_frames(n, h=96, w=128, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def block_pattern(h=64, w=96):
    """A frame whose orientation is unambiguous: distinct colours in three corners."""
    img = np.full((h, w, 3), 128, np.uint8)
    img[:16, :16] = (255, 0, 0)
    img[:16, -16:] = (0, 255, 0)
    img[-16:, :16] = (0, 0, 255)
    return img


def test_info_and_timestamps(tmp_path):
    clip = encode(tmp_path / "c.mp4", noise_frames(20), fps=25)
    info = open_video(clip)
    assert (info.width, info.height, info.n_frames, info.rotation) == (128, 96, 20, 0)
    assert info.fps == pytest.approx(25.0)
    assert info.codec == "h264"
    frames = list(iter_frames(clip))
    times = np.array([t for t, _ in frames])
    assert len(frames) == 20
    assert frames[0][1].shape == (96, 128, 3) and frames[0][1].dtype == np.uint8
    np.testing.assert_allclose(times, np.arange(20) / 25.0, atol=1e-9)
    assert len(list(iter_frames(clip, max_frames=7))) == 7


def test_variable_frame_rate_timestamps_kept(tmp_path):
    pts = np.array([0, 33, 50, 120, 130, 300, 310, 400, 520, 600])  # ms, irregular
    clip = encode(tmp_path / "vfr.mkv", noise_frames(len(pts)), fps=30, pts=pts,
                  time_base=Fraction(1, 1000))
    times = np.array([t for t, _ in iter_frames(clip)])
    np.testing.assert_allclose(times, pts / 1000.0, atol=1e-9)


@pytest.mark.parametrize("degrees", [90, -90, 180])
def test_rotation_metadata_applied(tmp_path, degrees):
    upright = block_pattern()
    k = degrees // 90
    coded = np.ascontiguousarray(np.rot90(upright, -k))  # what a rotated phone sensor stores
    clip = encode(tmp_path / f"rot{degrees}.mp4", [coded] * 3, rotation=degrees)
    info = open_video(clip)
    assert (info.width, info.height) == (upright.shape[1], upright.shape[0])
    assert info.rotation == degrees % 360
    _, rgb = next(iter(iter_frames(clip)))
    assert rgb.shape == upright.shape
    assert np.abs(rgb.astype(int) - upright).mean() < 6  # compression noise only
    _, raw = next(iter(iter_frames(clip, rotate=False)))
    assert raw.shape == coded.shape


def test_mjpeg_avi(tmp_path):
    clip = encode(tmp_path / "c.avi", noise_frames(5), codec="mjpeg", pix_fmt="yuvj420p")
    assert open_video(clip).codec == "mjpeg"
    assert len(list(iter_frames(clip))) == 5


def test_missing_directory_empty(tmp_path):
    with pytest.raises(CaptureError, match="no such file"):
        open_video(tmp_path / "nope.mp4")
    with pytest.raises(CaptureError, match="is a directory"):
        open_video(tmp_path)
    (tmp_path / "empty.mp4").write_bytes(b"")
    with pytest.raises(CaptureError, match="empty"):
        open_video(tmp_path / "empty.mp4")
    with pytest.raises(CaptureError, match="empty"):
        list(iter_frames(tmp_path / "empty.mp4"))


def test_not_a_video(tmp_path):
    p = tmp_path / "notes.mp4"
    p.write_text("this is a text file, not a video\n" * 20)
    with pytest.raises(CaptureError, match="not a video"):
        open_video(p)


def test_audio_only(tmp_path):
    p = tmp_path / "tone.m4a"
    sr = 44100
    x = (0.3 * np.sin(2 * np.pi * 440 * np.arange(sr) / sr)).astype(np.float32)[None]
    with av.open(str(p), "w") as c:
        s = c.add_stream("aac", rate=sr)
        for i in range(0, sr, 1024):
            f = av.AudioFrame.from_ndarray(np.ascontiguousarray(x[:, i:i + 1024]), format="flt", layout="mono")
            f.sample_rate = sr
            for pk in s.encode(f):
                c.mux(pk)
        for pk in s.encode():
            c.mux(pk)
    with pytest.raises(CaptureError, match="no video stream.*audio"):
        open_video(p)


def test_truncated_files(tmp_path, caplog):
    full = encode(tmp_path / "full.mp4", noise_frames(60, seed=1), faststart=True).read_bytes()
    # Index at the front, the data cut in half: the frames before the cut decode, with a warning.
    half = tmp_path / "half.mp4"
    half.write_bytes(full[: len(full) // 2])
    with caplog.at_level(logging.WARNING, logger="capture2face"):
        frames = list(iter_frames(half))
    assert 5 < len(frames) < 60
    assert "truncated" in caplog.text and f"decoded {len(frames)} of the 60" in caplog.text
    # Cut right after the index: nothing decodes -> a clear error.
    stub = tmp_path / "stub.mp4"
    stub.write_bytes(full[: len(full) // 50])
    with pytest.raises(CaptureError, match="truncated or corrupt"):
        open_video(stub)
    # Index at the end (the default for most writers) and the file cut: unreadable.
    tail = encode(tmp_path / "tail.mp4", noise_frames(30, seed=2)).read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(tail[: len(tail) // 2])
    with pytest.raises(CaptureError, match="truncated"):
        open_video(cut)


def test_prefetch_same_items_and_errors():
    assert list(prefetch(iter(range(100)), depth=3)) == list(range(100))

    def boom():
        yield 1
        raise CaptureError("bad frame")

    got = []
    with pytest.raises(CaptureError, match="bad frame"):
        for x in prefetch(boom()):
            got.append(x)
    assert got == [1]
    gen = prefetch(iter(range(10**6)), depth=2)
    assert next(gen) == 0
    gen.close()  # stops the worker without draining a million items

"""Segment-parallel tracking: the clip cut into segments tracked by landmarkers in
processes of their own, stitched into the Track a single landmarker makes."""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np
import pytest

from capture2face.io.video_input import frame_times, iter_frames, iter_segment, open_video
from capture2face.topology import IOD_PAIR
from capture2face.tracking import TrackOptions, segments, track_clip
from capture2face.tracking.landmarker import LandmarkerOptions
from capture2face.tracking.tracker import Tracker
from tests.helpers import truncated_copy

EYES = IOD_PAIR


def _parallel(clip, options, n_workers, **kwargs):
    """segments.track_parallel with a Tracker for this process's segment, as track_clip calls it."""
    info = open_video(clip)
    return segments.track_parallel(clip, info, options, n_workers, lambda: Tracker(info, options, None), **kwargs)


def _write(path, frames, fps=30, gop=None):
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=Fraction(fps))
        s.height, s.width = frames[0].shape[:2]
        s.pix_fmt = "yuv420p"
        s.options = {"crf": "18", **({"g": str(gop), "keyint_min": str(gop)} if gop else {})}
        for img in frames:
            for p in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


@pytest.fixture(scope="module")
def exit_clip(tmp_path_factory):
    """A synthetic performance (150 frames, 256 px) whose face leaves the frame for about
    a second mid-clip: gaps and the neutral pick must come out as from one landmarker."""
    from capture2face.synth import SynthOptions, synthesize

    path = tmp_path_factory.mktemp("segments") / "exit.mp4"
    return synthesize(path, SynthOptions(frames=150, size=256, seed=4, face_exit=True), progress=False)


def test_segment_decoding_gives_the_frames_of_a_whole_decode(tmp_path):
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (64, 96, 3), dtype=np.uint8)
    frames = [np.roll(base, 3 * i, axis=1) for i in range(70)]
    clip = _write(tmp_path / "gop.mp4", frames, gop=12)  # keyframes every 12: real seeks
    whole = list(iter_frames(clip))
    times = frame_times(clip)
    assert times is not None and len(times.pts) == 70
    for a, b in ((0, 5), (37, 61), (50, 70), (13, 14)):
        stop = int(times.pts[b]) if b < 70 else None
        got = list(iter_segment(clip, int(times.pts[a]), stop, rotation=0))
        assert [g[0] for g in got] == [t for t, _ in whole[a:b]]  # the same times, exactly
        for (_, rgb, _), (_, ref) in zip(got, whole[a:b]):
            np.testing.assert_array_equal(rgb, ref)


def test_damaged_clip_is_not_split(tmp_path, synthetic_clip):
    cut = truncated_copy(synthetic_clip.video_path, tmp_path)
    assert frame_times(cut) is None  # decoded from the start only, damage reported as before


def test_segments_stitch_into_the_sequential_track(exit_clip, monkeypatch, caplog):
    import logging

    caplog.set_level(logging.DEBUG, logger="capture2face")  # a fallback says why
    clip = exit_clip.video_path
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 40)
    monkeypatch.setattr(segments, "WARMUP_FRAMES", 12)
    seq = track_clip(clip, TrackOptions(workers=1), progress=False)
    options = TrackOptions(workers=3)
    plan = segments.plan_segments(clip, 3)
    assert plan is not None and plan.n_segments == 3
    par = _parallel(clip, options, 3, progress=False)
    assert par is not None, caplog.text  # no check failed: the clip was tracked in three segments

    # gaps and the neutral frame: the same frames, whichever landmarker saw them
    assert seq.n_gaps >= 1 and seq.n_long_gaps >= 1
    np.testing.assert_array_equal(par.times, seq.times)
    np.testing.assert_array_equal(par.presence, seq.presence)
    np.testing.assert_array_equal(par.held, seq.held)
    np.testing.assert_array_equal(par.interpolated, seq.interpolated)
    assert (par.n_gaps, par.n_long_gaps, par.n_faces_max) == (seq.n_gaps, seq.n_long_gaps, seq.n_faces_max)
    assert par.neutral_frame == seq.neutral_frame

    # landmarks: identical in the first segment (same landmarker, same frames), within
    # MediaPipe's frame-to-frame noise after the cuts
    iod = np.linalg.norm(seq.landmarks_px[:, EYES[0]] - seq.landmarks_px[:, EYES[1]], axis=-1)
    err = np.linalg.norm(par.landmarks_px - seq.landmarks_px, axis=-1) / iod[:, None]
    first = int(plan.starts[1]) - 5  # the zero-phase filter reaches a few frames back
    assert err[:first].max() < 1e-4
    assert np.median(err) < 0.003 and np.percentile(err, 99) < 0.02
    # and against the truth, as good as the sequential track
    truth = exit_clip.truth
    seen = seq.presence
    t_iod = np.linalg.norm(truth.landmarks_px[:, EYES[0]] - truth.landmarks_px[:, EYES[1]], axis=-1)[seen]
    e_seq = np.median(np.linalg.norm(seq.landmarks_px[seen] - truth.landmarks_px[seen], axis=-1) / t_iod[:, None])
    e_par = np.median(np.linalg.norm(par.landmarks_px[seen] - truth.landmarks_px[seen], axis=-1) / t_iod[:, None])
    assert e_par <= e_seq * 1.05 + 1e-4
    # MediaPipe's scores jump by up to ~0.2 for a few frames where its state differs (the
    # single- and several-face models take turns at other frames): on average they agree
    diff = np.abs(par.blendshapes - seq.blendshapes)
    assert diff.mean() < 0.005 and np.percentile(diff.max(1), 90) < 0.05


def test_short_clip_and_face_index_track_with_one_landmarker(exit_clip, monkeypatch):
    clip = exit_clip.video_path
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 80)
    assert segments.plan_segments(clip, 4) is None  # 150 frames < two segments of 80
    assert _parallel(clip, TrackOptions(workers=4), 4, progress=False) is None
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 40)
    assert _parallel(clip, TrackOptions(workers=2, landmarker=LandmarkerOptions(face=0)), 2,
                                   progress=False) is None


def test_same_face_across_a_cut():
    a = [(100.0, 100.0, 80.0), None, (102.0, 101.0, 80.0)]
    assert segments._same_face(a, [(101.0, 100.0, 81.0), (0.0, 0.0, 1.0), (103.0, 100.0, 80.0)], True)
    assert not segments._same_face(a, [(300.0, 100.0, 90.0), None, (301.0, 100.0, 90.0)], True)
    assert segments._same_face([None, None], [None, (5.0, 5.0, 50.0)], several_faces=False)
    assert not segments._same_face([None, None], [None, (5.0, 5.0, 50.0)], several_faces=True)


def test_plan_gives_the_first_segment_the_warmup_and_covers_every_frame(tmp_path, monkeypatch):
    frames = [np.full((32, 32, 3), i, np.uint8) for i in range(100)]
    clip = _write(tmp_path / "c.mp4", frames, gop=10)
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 20)
    plan = segments.plan_segments(clip, 3)
    starts = plan.starts
    assert starts[0] == 0 and starts[-1] == 100 and np.all(np.diff(starts) > 0)
    lengths = np.diff(starts)
    assert lengths[0] == lengths[1] + segments.WARMUP_FRAMES + (100 - segments.WARMUP_FRAMES) % 3
    assert segments.plan_segments(clip, 3, max_frames=50).starts[-1] == 50
    job = plan.job(2, str(clip), 0, (32, 32), str(tmp_path), None)
    assert job["first_pts"] == plan.times.pts[starts[2] - segments.WARMUP_FRAMES]
    assert job["stop_pts"] is None and job["frames"] == lengths[2]


def test_batch_tracks_each_clip_with_one_landmarker(monkeypatch, tmp_path, sample_clip):
    import capture2face.batch as batch
    from capture2face.pipeline import RunOptions

    seen = {}

    def pool(clips, todo, out, options, n_jobs, done):
        seen["options"] = options
        for i in todo:
            done(i, {"status": "ok", "seconds": 0.0, "error": None})

    monkeypatch.setattr(batch, "_run_pool", pool)
    copy = tmp_path / "b.mp4"
    copy.write_bytes(sample_clip.read_bytes())
    batch.run_batch([sample_clip, copy], tmp_path / "out", RunOptions(), jobs=2, progress=False)
    assert seen["options"].track.workers == 1
    batch.run_batch([sample_clip, copy], tmp_path / "out", RunOptions(track=TrackOptions(workers=2)), jobs=2,
                    progress=False)
    assert seen["options"].track.workers == 2  # an explicit choice is kept
    assert RunOptions().track.workers is None


def test_a_failed_stitch_check_falls_back_to_one_landmarker(exit_clip, monkeypatch):
    clip = exit_clip.video_path
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 40)
    monkeypatch.setattr(segments, "_same_face", lambda *a: False)  # as if a worker took another face
    assert _parallel(clip, TrackOptions(workers=2), 2, progress=False) is None
    track = track_clip(clip, TrackOptions(workers=2), progress=False)
    seq = track_clip(clip, TrackOptions(workers=1), progress=False)
    np.testing.assert_array_equal(track.landmarks_px, seq.landmarks_px)  # tracked by one, from the start


def test_workers_finishing_before_this_process_are_stitched(exit_clip, monkeypatch, caplog):
    import logging
    import time

    from capture2face.tracking import tracker as tracker_mod

    caplog.set_level(logging.DEBUG, logger="capture2face")
    clip = exit_clip.video_path
    monkeypatch.setattr(segments, "MIN_SEGMENT_FRAMES", 40)
    monkeypatch.setattr(segments, "WARMUP_FRAMES", 12)
    process = tracker_mod.Tracker.process

    def slow(self, t, rgb):  # this process's segment ends long after the workers' results came
        time.sleep(0.03)
        return process(self, t, rgb)

    monkeypatch.setattr(tracker_mod.Tracker, "process", slow)
    par = _parallel(clip, TrackOptions(workers=3), 3, progress=False)
    assert par is not None, caplog.text
    monkeypatch.setattr(tracker_mod.Tracker, "process", process)
    seq = track_clip(clip, TrackOptions(workers=1), progress=False)
    np.testing.assert_array_equal(par.presence, seq.presence)
    assert par.neutral_frame == seq.neutral_frame

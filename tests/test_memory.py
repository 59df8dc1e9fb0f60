"""Memory that does not grow with clip length: disk-backed frame arrays, windowed tracking
passes and windowed retargeting give what the whole-clip computations give."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import capture2face.retarget.driver as retarget_mod
import capture2face.tracking.tracker as tracking_mod
from capture2face.io.framestore import FrameArray, take_points
from capture2face.io.video_input import VideoInfo
from capture2face.retarget import RetargetOptions, retarget
from capture2face.retarget.windows import SpilledMedian, frame_windows
from capture2face.synth.trajectories import random_performance
from capture2face.topology import BLENDSHAPE_NAMES, N_LANDMARKS
from capture2face.tracking import Track, TrackOptions, build_track
from capture2face.tracking.filtering import CausalOneEuro, OneEuro, one_euro
from capture2face.tracking.head_pose import canonical_mesh
from capture2face.tracking.landmarker import FaceObservation
from tests.helpers import perfect_track


# ---- FrameArray ----------------------------------------------------------------------
def test_frame_array_round_trip_and_indexing(tmp_path):
    x = np.random.default_rng(0).random((300, 7, 3)).astype(np.float32)
    fa = FrameArray(tmp_path / "a.f32", (7, 3), np.float32)
    for s in range(0, 300, 64):
        fa.append(x[s:s + 64])
    fa.write(10, x[10:12] + 1.0)
    x[10:12] += 1.0
    assert fa.shape == x.shape and len(fa) == 300
    np.testing.assert_array_equal(np.asarray(fa), x)
    np.testing.assert_array_equal(fa[5], x[5])
    np.testing.assert_array_equal(fa[-1], x[-1])
    np.testing.assert_array_equal(fa[20:40, 3], x[20:40, 3])
    np.testing.assert_array_equal(fa[::7], x[::7])
    np.testing.assert_array_equal(fa[50:10:-3], x[50:10:-3])
    np.testing.assert_array_equal(fa[x[:, 0, 0] > 0.5], x[x[:, 0, 0] > 0.5])
    np.testing.assert_array_equal(fa.read_rows(np.array([3, 4, 5, 99, 0])), x[[3, 4, 5, 99, 0]])
    np.testing.assert_array_equal(np.concatenate(list(fa.iter_chunks(chunk_bytes=1000))), x)
    ro = fa.reopen_readonly()
    np.testing.assert_array_equal(ro[123], x[123])
    with pytest.raises(ValueError):
        ro.append(x[:1])
    # A few points of every frame, read in blocks (a block size that does not divide F).
    ids = [6, 0, 3]
    for frames in (fa, x):
        got = take_points(frames, ids, chunk=64)
        assert got.dtype == np.float64 and got.shape == (300, 3, 3)
        np.testing.assert_array_equal(got, x[:, ids])


def test_track_save_streams_disk_backed_arrays(tmp_path):
    rng = np.random.default_rng(1)
    n = 50
    head = FrameArray(tmp_path / "head.f32", (N_LANDMARKS, 3), np.float32)
    values = rng.random((n, N_LANDMARKS, 3)).astype(np.float32)
    head.append(values)
    track = Track(times=np.arange(n) / 30.0, landmarks_px=np.zeros((n, N_LANDMARKS, 2), np.float32),
                  landmarks_depth=np.zeros((n, N_LANDMARKS), np.float32), landmarks_head=head,
                  presence=np.ones(n, bool), interpolated=np.zeros(n, bool), held=np.zeros(n, bool),
                  blendshapes=np.zeros((n, 52), np.float32), blendshape_names=list(BLENDSHAPE_NAMES),
                  head_pose=np.tile(np.eye(4, dtype=np.float32), (n, 1, 1)), neutral_frame=3,
                  width=64, height=64, fps=30.0)
    track.save(tmp_path / "track.npz")
    back = Track.load(tmp_path / "track.npz")
    assert back.landmarks_head.dtype == np.float32
    np.testing.assert_array_equal(back.landmarks_head, values)
    assert back.neutral_frame == 3


# ---- tracking passes -------------------------------------------------------------------
def test_causal_one_euro_in_blocks_equals_one_call():
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.02, 0.05, 200))
    x = np.cumsum(rng.normal(0, 0.1, (200, 5, 3)), axis=0)
    p = OneEuro(0.5, 0.2, 1.0, zero_phase=False)
    f = CausalOneEuro(p, speed_axis=-1)
    blocks = np.concatenate([f(x[s:s + 37], t[s:s + 37]) for s in range(0, 200, 37)])
    np.testing.assert_array_equal(blocks, one_euro(x, t, p, speed_axis=-1))
    assert np.abs(blocks - x).max() > 0.01  # it did filter


def _observations(frames: int, seed: int = 0):
    """Synthetic MediaPipe observations: the canonical face moving and deforming a
    little, with short and long gaps (no face) including at the start and end."""
    rng = np.random.default_rng(seed)
    verts = canonical_mesh().vertices.astype(np.float64)
    verts = np.concatenate([verts, verts[:N_LANDMARKS - len(verts)]])
    times = np.arange(frames) / 30.0
    missing = np.zeros(frames, bool)
    missing[[0, 1, 40, 41, 42, 90, frames - 1]] = True
    missing[120:150] = True  # one second: a long gap, held
    obs = []
    for f in range(frames):
        if missing[f]:
            obs.append(None)
            continue
        pts = verts * (1.0 + 0.01 * np.sin(0.1 * f)) + rng.normal(0, 0.05, verts.shape)
        norm = np.empty_like(pts)
        norm[:, 0] = 0.5 + pts[:, 0] / 40.0 + 0.02 * np.sin(0.05 * f)
        norm[:, 1] = 0.5 - pts[:, 1] / 40.0
        norm[:, 2] = -pts[:, 2] / 40.0
        norm = norm.astype(np.float32)
        scores = rng.random(len(BLENDSHAPE_NAMES)).astype(np.float32) * 0.3
        obs.append(FaceObservation(landmarks_norm=norm, landmarks_px=norm[:, :2] * 256, depth=norm[:, 2] * 256,
                                   blendshapes=scores, matrix=np.eye(4, dtype=np.float32), n_faces=1))
    return list(times), obs


def test_windowed_tracking_passes_match_one_window(monkeypatch, tmp_path):
    frames = 260
    times, obs = _observations(frames)
    info = VideoInfo(path="synthetic.mp4", width=256, height=256, fps=30.0, n_frames=frames,
                     duration=frames / 30.0, codec="h264", rotation=0)
    options = TrackOptions()
    monkeypatch.setattr(tracking_mod, "FLUSH_FRAMES", 10**6)
    monkeypatch.setattr(tracking_mod, "WINDOW_FRAMES", 10**6)
    whole = build_track(times, obs, (256, 256), info, options)
    monkeypatch.setattr(tracking_mod, "FLUSH_FRAMES", 17)
    monkeypatch.setattr(tracking_mod, "WINDOW_FRAMES", 23)
    small = build_track(times, obs, (256, 256), info, options)
    builder = tracking_mod.TrackBuilder(info, options, workdir=tmp_path / "work")
    for t, o in zip(times, obs):
        builder.add(t, o, (256, 256))
    on_disk = builder.finish()
    assert isinstance(on_disk.landmarks_head, FrameArray)
    assert whole.n_gaps == 5 and whole.n_long_gaps == 1  # start, 40-42, 90, 120-150, end
    assert whole.held[120:150].all() and whole.interpolated[40:43].all()
    for track in (small, on_disk):
        for name in ("landmarks_px", "landmarks_depth", "landmarks_head"):
            np.testing.assert_allclose(np.asarray(getattr(track, name)), getattr(whole, name), rtol=0, atol=1e-5)
        np.testing.assert_array_equal(track.head_pose, whole.head_pose)
        np.testing.assert_array_equal(track.blendshapes, whole.blendshapes)
        assert track.neutral_frame == whole.neutral_frame
    # A long gap holds the last tracked frame's landmarks exactly (before filtering: px).
    np.testing.assert_array_equal(np.asarray(on_disk.landmarks_px[120:150]),
                                  np.repeat(whole.landmarks_px[119:120], 30, 0))
    # The disk-backed track saves and loads like the in-memory one.
    on_disk.save(tmp_path / "a.npz")
    whole.save(tmp_path / "b.npz")
    a, b = Track.load(tmp_path / "a.npz"), Track.load(tmp_path / "b.npz")
    np.testing.assert_allclose(a.landmarks_head, b.landmarks_head, atol=1e-5)


# ---- retargeting windows ------------------------------------------------------------------
@pytest.mark.parametrize("frames", [1000, 1001, 3000, 18000])
def test_frame_windows_cover_and_fade_to_one(frames):
    windows = frame_windows(frames, 1000, 100)
    total, owned = np.zeros(frames), np.zeros(frames, int)
    for w in windows:
        assert w.stop - w.start <= 1000
        total[w.start:w.stop] += w.fade
        owned[w.own_start:w.own_stop] += 1
    np.testing.assert_allclose(total, 1.0, atol=1e-12)
    assert (owned == 1).all()
    for a, b in zip(windows, windows[1:]):
        assert a.stop - b.start >= 100  # neighbours share at least the overlap
        assert a.fade[-25:].max() < 1e-9  # a window's last quarter-overlap carries no weight
    assert len(windows) == (1 if frames <= 1000 else 1 + int(np.ceil((frames - 1000) / 900)))


def test_spilled_median_is_exact():
    rng = np.random.default_rng(3)
    x = rng.random((1000, 37))
    with SpilledMedian(37) as med:
        for s in range(0, 1000, 130):
            med.add(x[s:s + 130])
        SpilledMedian.BLOCK_BYTES = 8 * 1000 * 5  # several column ranges
        try:
            got = med.median()
        finally:
            SpilledMedian.BLOCK_BYTES = 8 << 20
    np.testing.assert_array_equal(got, np.median(x, axis=0))


@pytest.fixture(scope="module")
def noisy_track(avatar):
    perf = random_performance(avatar, 240, seed=5)
    return perfect_track(avatar, perf, noise=0.05)


def test_windowed_retarget_matches_whole_clip(avatar, noisy_track, monkeypatch):
    whole_opts = RetargetOptions(window_frames=10**9)
    windowed = RetargetOptions(window_frames=100, window_overlap=40)
    assert len(frame_windows(noisy_track.n_frames, 100, 40)) == 4
    # Default solver: windows differ only by where ADMM stops (tolerance 1e-3).
    a, b = retarget(noisy_track, avatar, whole_opts), retarget(noisy_track, avatar, windowed)
    assert np.abs(a.bone_positions - b.bone_positions).max() < 2e-3
    assert np.abs(a.blend_weights - b.blend_weights).max() < 2e-3
    # Converged solves: the windows reproduce the whole-clip solution to float32 precision.
    original = retarget_mod._joint_solver

    def converged(*args, **kwargs):
        solver = original(*args, **kwargs)
        solver.tolerance, solver.iterations = 1e-7, 5000
        return solver

    monkeypatch.setattr(retarget_mod, "_joint_solver", converged)
    a, b = retarget(noisy_track, avatar, whole_opts), retarget(noisy_track, avatar, windowed)
    np.testing.assert_allclose(b.bone_positions, a.bone_positions, rtol=0, atol=2e-5)
    np.testing.assert_allclose(b.blend_weights, a.blend_weights, rtol=0, atol=2e-5)
    np.testing.assert_allclose(b.influences, a.influences, rtol=0, atol=2e-5)
    np.testing.assert_allclose(b.zone_weights, a.zone_weights, rtol=0, atol=2e-5)


def test_windowed_retarget_direct_and_bone_only_modes(avatar, noisy_track):
    for opts in ({"joint_solve": False}, {"solve_blend_weights": False}):
        a = retarget(noisy_track, avatar, RetargetOptions(window_frames=10**9, **opts))
        b = retarget(noisy_track, avatar, RetargetOptions(window_frames=100, window_overlap=40, **opts))
        assert np.abs(a.bone_positions - b.bone_positions).max() < 2e-3
        assert np.abs(a.blend_weights - b.blend_weights).max() < 2e-3


def test_heap_settings_apply_on_glibc():
    from capture2face.runtime.heap import bound_heap, release_free_memory

    applied = bound_heap()
    assert applied == (sys.platform.startswith("linux") and "glibc" in " ".join(__import__("platform").libc_ver()))
    release_free_memory()  # must not raise anywhere

"""``capture2face bench`` reports every figure; the memory check's looped clip is exact."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

KEYS = ["decode_fps", "mediapipe_fps", "track_fps", "track_fps_parallel", "retarget_ms_per_frame", "wrinkle_ms_per_frame", "render_fps_wrinkles_off",
        "render_fps_wrinkles_auto", "render_fps_wrinkles_dynamic", "encode_fps", "end_to_end_fps", "peak_rss_mb",
        "gl_renderer"]


@pytest.mark.slow
def test_bench_cli_reports_every_figure(tmp_path):
    out = tmp_path / "bench.json"
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    result = subprocess.run([sys.executable, "-m", "capture2face", "-q", "bench", "--size", "128", "--frames", "24",
                             "--json", str(out)], capture_output=True, text=True, timeout=900, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    figures = json.loads(out.read_text())
    assert figures == json.loads(result.stdout)
    for key in KEYS[:-1]:
        assert isinstance(figures[key], (int, float)) and np.isfinite(figures[key]) and figures[key] > 0, key
    assert isinstance(figures["gl_renderer"], str) and figures["gl_renderer"]
    # Wall-clock rates of separately timed stages are not compared here: on a shared
    # 2-core machine their order flips with load (CI saw end_to_end 19.1 > track 16.5).
    # Processor time: every stage costs some, the whole pipeline more than tracking alone,
    # and no run beats the bound its own work sets on this many cores.
    cpu = figures["cpu_ms_per_frame"]
    assert set(cpu) == {"decode", "track", "track_parallel", "render_wrinkles_auto", "encode", "end_to_end"}
    assert all(v > 0 for v in cpu.values())
    assert cpu["end_to_end"] > cpu["track"]
    assert figures["cpu_cores"] >= 1
    assert figures["end_to_end_fps_cpu_bound"] == pytest.approx(figures["cpu_cores"] * 1000 / cpu["end_to_end"], rel=0.01)
    assert figures["end_to_end_fps"] <= figures["end_to_end_fps_cpu_bound"] * 1.01
    assert figures["end_to_end_over_cpu_bound"] == pytest.approx(
        figures["end_to_end_fps"] / figures["end_to_end_fps_cpu_bound"], rel=0.01)
    assert figures["track_overhead_ms_per_frame"] == pytest.approx(
        1000 / figures["track_fps"] - 1000 / figures["mediapipe_fps"], rel=0.02, abs=0.05)
    assert 1 <= figures["track_workers"] <= figures["cpu_cores"]
    assert figures["peak_rss_mb"] > 50  # MediaPipe + GL + NumPy are loaded: not a bogus figure
    assert (figures["size"], figures["frames"]) == (128, 24)
    assert set(figures["goals"]) and all(isinstance(v, bool) for v in figures["goals"].values())
    # Render drivers are timed interleaved: each figure is the median of its rounds, and
    # the wrinkle cost is the median per-round ratio.
    rounds = figures["render_rounds_fps"]
    assert set(rounds) == {"off", "auto", "dynamic"} and len({len(v) for v in rounds.values()}) == 1
    assert len(rounds["off"]) >= 3
    for driver, fps in rounds.items():
        assert figures[f"render_fps_wrinkles_{driver}"] == pytest.approx(np.median(fps), rel=0.01, abs=0.02)
    ratio = np.median(np.array(rounds["auto"]) / np.array(rounds["off"]))
    assert figures["render_auto_over_off"] == pytest.approx(ratio, rel=0.02)
    assert figures["goals"]["render auto >= 0.9 x off"] == (figures["render_auto_over_off"] >= 0.9)


def test_looped_clip_repeats_the_source_exactly(tmp_path):
    from capture2face.bench import loop_clip
    from capture2face.io.video_input import iter_frames, open_video

    sys.path.insert(0, os.path.dirname(__file__))
    from test_bad_input import write_video

    src = write_video(tmp_path / "src.mp4", 25, size=64, seed=3)  # 1 s at 25 fps
    n = loop_clip(src, tmp_path / "long.mp4", seconds=3.5)
    assert n == 100  # whole loops: 4 x 25 frames
    info = open_video(tmp_path / "long.mp4")
    assert info.fps == pytest.approx(25.0) and info.duration == pytest.approx(4.0, abs=0.05)
    source = [f for _, f in iter_frames(src)]
    looped = list(iter_frames(tmp_path / "long.mp4"))
    assert len(looped) == 100
    times = np.array([t for t, _ in looped])
    np.testing.assert_allclose(np.diff(times), 1 / 25, atol=1e-6)  # no timestamp jump at the seams
    for k in (0, 24, 25, 26, 99):
        np.testing.assert_array_equal(looped[k][1], source[k % 25])  # decoded identically

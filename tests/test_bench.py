"""``capture2face bench`` reports every figure; the memory check's looped clip is exact."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.helpers import write_video

KEYS = ["decode_fps", "mediapipe_fps", "track_fps", "track_fps_parallel", "retarget_ms_per_frame",
        "wrinkle_ms_per_frame", "render_fps_wrinkles_off", "render_fps_wrinkles_auto", "render_fps_wrinkles_dynamic",
        "encode_fps", "end_to_end_fps", "peak_rss_mb", "gl_renderer"]


@pytest.mark.slow
def test_bench_cli_reports_every_figure(tmp_path):
    """Each rate is checked against clocks outside the bench: the bench's process as the OS
    accounts for it (wall time, processor time and peak memory from ``wait4``). Every
    stage's time (frames / rate) fits in the process's wall time and is no less than its
    own processor time spread over the cores; the processor times per frame add up to no
    more than the process used; the peak memory is the process's."""
    out = tmp_path / "bench.json"
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    frames = 24
    cmd = [sys.executable, "-m", "capture2face", "-q", "bench", "--size", "128", "--frames", str(frames),
           "--json", str(out)]
    start = time.perf_counter()
    with open(tmp_path / "stdout", "w") as so, open(tmp_path / "stderr", "w") as se:
        proc = subprocess.Popen(cmd, stdout=so, stderr=se, env=env)
        try:
            _, status, usage = os.wait4(proc.pid, 0)  # the child's own rusage
        except BaseException:
            proc.kill()
            raise
    wall = time.perf_counter() - start
    stdout, stderr = (tmp_path / "stdout").read_text(), (tmp_path / "stderr").read_text()
    assert os.waitstatus_to_exitcode(status) == 0, stderr[-3000:]
    proc.returncode = 0
    figures = json.loads(out.read_text())
    assert figures == json.loads(stdout)
    assert (figures["size"], figures["frames"]) == (128, frames)
    cores = len(os.sched_getaffinity(0))
    assert figures["cpu_cores"] == cores
    assert isinstance(figures["gl_renderer"], str) and figures["gl_renderer"]

    # Seconds each stage took, from its rate: decode, tracking (one landmarker, then
    # several), the renders (RENDER_ROUNDS rounds of min(frames, 40) frames per driver),
    # the encode (ENCODE_FRAMES frames) and the whole run.
    from capture2face.bench import ENCODE_FRAMES, RENDER_FRAMES_MAX, RENDER_ROUNDS

    rounds = figures["render_rounds_fps"]
    assert set(rounds) == {"off", "auto", "dynamic"} and all(len(v) == RENDER_ROUNDS for v in rounds.values())
    n_render = min(frames, RENDER_FRAMES_MAX)
    stage_s = {
        "decode": frames / figures["decode_fps"],
        "track": frames / figures["track_fps"],
        "track_parallel": frames / figures["track_fps_parallel"],
        "render_wrinkles_auto": RENDER_ROUNDS * n_render / figures["render_fps_wrinkles_auto"],
        "encode": ENCODE_FRAMES / figures["encode_fps"],
        "end_to_end": frames / figures["end_to_end_fps"],
    }
    render_s = sum(n_render / fps for v in rounds.values() for fps in v)
    timed = (figures["synth_seconds"] + sum(stage_s.values()) - stage_s["render_wrinkles_auto"] + render_s
             + 3 * frames * (figures["retarget_ms_per_frame"] + figures["wrinkle_ms_per_frame"]) / 1000)
    # The stages ran one after another inside the process (which also imported, built the
    # avatar and started renderers): together within its wall time, and most of it.
    assert 0.3 * wall < timed < wall, (timed, wall)
    # MediaPipe alone is part of tracking: its calls take less time than the whole stage.
    assert frames / figures["mediapipe_fps"] < stage_s["track"]
    # The run's own clock (report.json's seconds) sits inside the bench's clock of it; what
    # lies outside (closing the segment workers) is short, even on a loaded machine.
    total = figures["end_to_end_seconds"]["total"]
    assert total <= stage_s["end_to_end"] <= total + max(2.0, 0.25 * total)
    # Processor time: no stage used more than its wall time on every core, and all of them
    # together no more than the process (and its waited-for workers) used in all.
    cpu = figures["cpu_ms_per_frame"]
    assert set(cpu) == set(stage_s)
    for stage, seconds in stage_s.items():
        n = {"render_wrinkles_auto": RENDER_ROUNDS * n_render, "encode": ENCODE_FRAMES}.get(stage, frames)
        assert 0 < cpu[stage] * n / 1000 <= cores * seconds * 1.05 + 0.02, stage
    process_cpu = usage.ru_utime + usage.ru_stime
    assert sum(cpu[k] * (ENCODE_FRAMES if k == "encode" else frames) / 1000
               for k in cpu if k != "render_wrinkles_auto") \
        + cpu["render_wrinkles_auto"] * RENDER_ROUNDS * n_render / 1000 < process_cpu
    # Peak memory: the process's own, as the OS measured it (wait4 reports the larger of it
    # and its children's; the tracking workers are smaller).
    os_peak_mb = usage.ru_maxrss / 1024.0
    assert 0.9 * os_peak_mb <= figures["peak_rss_mb"] <= os_peak_mb * 1.001
    assert 1 <= figures["track_workers"] <= cores
    goals = figures["goals"]
    assert goals["render auto >= 0.9 x off"] == (figures["render_auto_over_off"] >= 0.9)


def test_looped_clip_repeats_the_source_exactly(tmp_path):
    from capture2face.bench import loop_clip
    from capture2face.io.video_input import iter_frames, open_video

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


@pytest.mark.slow
def test_bench_calibration_times_calibrate_on_the_protocols_take(tmp_path):
    """``bench --calibration``: the take is the whole protocol, performed (the avatar's
    steps are found), and the time per 30 s is the measured wall time scaled by the take's
    length, inside the process's own wall time."""
    from capture2face.calibration.protocol import PROTOCOL

    out = tmp_path / "bench.json"
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "capture2face", "bench", "--calibration", "--size", "160",
                           "--json", str(out)], capture_output=True, text=True, env=env, check=False)
    wall = time.perf_counter() - start
    assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads(out.read_text())
    assert figures["steps"] == len(PROTOCOL) and figures["steps_found"] >= 0.5 * len(PROTOCOL)
    assert figures["take_seconds"] == pytest.approx(figures["take_frames"] / 30.0, abs=1e-3)
    assert figures["take_seconds"] > 20
    assert figures["calibrate_seconds_per_30s"] == pytest.approx(
        figures["calibrate_seconds"] * 30 / figures["take_seconds"], rel=1e-3)
    assert figures["synth_seconds"] + figures["calibrate_seconds"] < wall
    (goal, met), = figures["goals"].items()
    assert met == (figures["calibrate_seconds_per_30s"] <= 10.0)
    assert "calibrate " in done.stderr and "per 30 s" in done.stderr  # the summary line

"""``capture2face bench``: every stage alone and the whole pipeline, in one run, on a
synthetic clip; and a memory check (peak RSS of a long clip against a short one).

Figures (all frames per second of wall time unless named otherwise):

* ``decode_fps``: :func:`~capture2face.io.video_input.iter_frames` alone.
* ``mediapipe_fps``: MediaPipe's Face Landmarker alone (single-face, VIDEO mode, its
  Python API), only its calls timed, on the same frames.
* ``track_fps``: :func:`~capture2face.tracking.track_clip` with one landmarker (decode +
  MediaPipe + head pose + gaps + filters + neutral pick); ``track_overhead_ms_per_frame``
  = 1000 / ``track_fps`` - 1000 / ``mediapipe_fps``: what the track stage adds.
* ``track_fps_parallel``: the same with ``track_workers`` landmarkers on segments of the
  clip (:mod:`capture2face.tracking.segments`), the workers' start-up included (``run``
  starts them before its checks, so there it is partly hidden).
* ``retarget_ms_per_frame``: :func:`~capture2face.retarget.retarget` without its wrinkle
  part (RBF fit and mapping, bone/morph solve, zone weights), best of 3.
* ``wrinkle_ms_per_frame``: the wrinkle influences alone (Dutreve §5.1 pose evaluation,
  grouping, rest influence, region means), best of 3. The two add up to ``retarget()``.
* ``render_fps_wrinkles_{off,auto,dynamic}``: the GL renderer at ``size`` with ``run``'s
  anti-aliasing (:func:`~capture2face.pipeline.run_render_options`; FXAA on software GL),
  read-back included, on the clip's retargeted performance. The three drivers are timed
  interleaved: ``RENDER_ROUNDS`` rounds, each rendering the same frames with every driver
  (the starting driver rotating), and each figure is the driver's **median** round, so a
  neighbour's load burst hits all three alike. ``render_auto_over_off`` is the median of
  the per-round ratios auto / off (the wrinkle shader's cost: 1 - that ratio).
* ``encode_fps``: H.264 encoding of rendered frames at ``size``.
* ``end_to_end_fps``: :func:`capture2face.pipeline.run` with default options (avatar.mp4,
  compare.mp4 and every export), clip frames / total seconds;
  ``end_to_end_over_cpu_bound`` its ratio to ``end_to_end_fps_cpu_bound`` (below).
* ``peak_rss_mb``: this process's peak resident memory.
* ``cpu_ms_per_frame``: processor time (user + system, every thread of the process:
  MediaPipe's, llvmpipe's, the encoders'; and the tracking worker processes') per frame of
  the decode, track, render (``auto`` driver), encode and end-to-end measurements. With
  ``cpu_cores`` cores, no scheduling can run the pipeline faster than ``end_to_end_fps_cpu_bound`` = cores x 1000 /
  ``cpu_ms_per_frame["end_to_end"]``: the work itself caps the speed, whatever overlaps.

``bench --calibration`` instead times ``capture2face calibrate`` (:func:`calibration_bench`):
the range-of-motion protocol performed by the built-in avatar as an ARKit character
(``synth --rom``), tracked and learned as ``calibrate`` does; ``calibrate_seconds_per_30s``
is its wall time per 30 s of take (the issue's goal: under 10 s on 2 cores).
"""

from __future__ import annotations

import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture2face.character.load import load_character
from capture2face.errors import CaptureError
from capture2face.gltf.arkit_export import export_arkit_character
from capture2face.io.atomic import atomic_path
from capture2face.io.video_input import iter_frames
from capture2face.io.video_output import VideoWriter
from capture2face.models.face_model import find_face_model
from capture2face.pipeline import (
    RunOptions,
    avatar_head_poses,
    run,
    run_render_options,
    track_stage,
)
from capture2face.pipeline.calibration import learn_calibration
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.retarget import RetargetOptions, retarget
from capture2face.rig import influences as inf
from capture2face.rig.avatar import default_avatar
from capture2face.runtime.cores import free_cores
from capture2face.synth import SynthOptions, synthesize
from capture2face.tracking.landmarker import LandmarkerOptions, _mediapipe_landmarker

RENDER_FRAMES_MAX = 40  # frames per round and driver; the renderer's speed is per frame
RENDER_ROUNDS = 5
ENCODE_FRAMES = 120


def _cpu_seconds() -> float:
    """Processor seconds of this process (all threads) and of its finished children (the
    tracking workers)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


class _Clock:
    """Wall and CPU seconds (all threads, and children waited for) of a ``with`` block."""

    def __enter__(self) -> _Clock:
        self._wall, self._cpu = time.perf_counter(), _cpu_seconds()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self._wall
        self.cpu = _cpu_seconds() - self._cpu


def cpu_cores() -> int:
    """Cores this process may run on."""
    return free_cores()


def mediapipe_alone(clip, max_frames: int | None = None) -> float:
    """Frames per second of MediaPipe's Face Landmarker alone on ``clip``'s frames (one
    single-face landmarker in VIDEO mode through its Python API; decoding not timed)."""
    import mediapipe as mp

    lm = _mediapipe_landmarker(find_face_model(None), LandmarkerOptions(), 1)
    busy, n = 0.0, 0
    try:
        for t, rgb in iter_frames(clip, max_frames=max_frames):
            t0 = time.perf_counter()
            image = mp.Image(image_format=mp.ImageFormat.SRGB, data=rgb)
            lm.detect_for_video(image, int(round(t * 1000)))
            busy += time.perf_counter() - t0
            n += 1
    finally:
        lm.close()
    return n / busy


def _best_of(fn, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _wrinkle_part(animation, rig):
    """What retarget() computes for wrinkles from the solved bones (Dutreve §5.1-5.2)."""
    influences = inf.rig_influences(animation.bone_positions, rig)
    inf.rest_influence(influences)
    inf.region_influence(influences, rig)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports KiB, macOS bytes)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024.0 * 1024.0) if sys.platform == "darwin" else rss / 1024.0


def run_bench(size: int = 512, frames: int = 300, progress: bool = True, seed: int = 0) -> dict:
    """Measure each stage and the whole pipeline on a synthetic clip of ``frames`` frames
    at ``size`` x ``size``. Returns a dict of figures (see the module doc)."""
    if frames < 10:
        raise CaptureError(f"--frames must be at least 10 (got {frames})")
    result: dict = {"size": int(size), "frames": int(frames)}
    rig = default_avatar()
    with tempfile.TemporaryDirectory(prefix="capture2face-bench-") as tmp:
        tmp = Path(tmp)
        clip = tmp / "bench.mp4"
        t = time.perf_counter()
        synthesize(clip, SynthOptions(frames=frames, size=size, seed=seed), progress=progress)
        result["synth_seconds"] = round(time.perf_counter() - t, 2)

        cpu_ms: dict[str, float] = {}
        with _Clock() as clock:
            n = sum(1 for _ in iter_frames(clip))
        result["decode_fps"] = n / clock.wall
        cpu_ms["decode"] = 1000.0 * clock.cpu / n

        result["mediapipe_fps"] = mediapipe_alone(clip)
        options = RunOptions(render=RenderOptions(size=size))
        with _Clock() as clock:
            track = track_stage(clip, replace(options, track=replace(options.track, workers=1)), progress=progress)
        result["track_fps"] = track.n_frames / clock.wall
        cpu_ms["track"] = 1000.0 * clock.cpu / track.n_frames
        result["track_overhead_ms_per_frame"] = 1000.0 / result["track_fps"] - 1000.0 / result["mediapipe_fps"]
        workers = options.track.n_workers()
        with _Clock() as clock:
            parallel = track_stage(clip, options, progress=progress)
        result["track_fps_parallel"] = parallel.n_frames / clock.wall
        result["track_workers"] = workers
        cpu_ms["track_parallel"] = 1000.0 * clock.cpu / parallel.n_frames
        del parallel

        animation = retarget(track, rig, RetargetOptions())
        total_s = _best_of(lambda: retarget(track, rig, RetargetOptions()))
        wrinkle_s = _best_of(lambda: _wrinkle_part(animation, rig))
        result["retarget_ms_per_frame"] = 1000.0 * max(total_s - wrinkle_s, 0.0) / track.n_frames
        result["wrinkle_ms_per_frame"] = 1000.0 * wrinkle_s / track.n_frames

        rendered, render_figures, cpu_ms["render_wrinkles_auto"] = _render_rounds(
            rig, animation, replace(options, compare=False), progress)
        result.update(render_figures)

        with _Clock() as clock, VideoWriter(tmp / "encode.mp4", track.fps, (size, size)) as out:
            for i in range(ENCODE_FRAMES):
                out.write(rendered[i % len(rendered)])
        result["encode_fps"] = ENCODE_FRAMES / clock.wall
        cpu_ms["encode"] = 1000.0 * clock.cpu / ENCODE_FRAMES

        with _Clock() as clock:
            report = run(clip, tmp / "out", options, progress=progress)
        result["end_to_end_fps"] = report["frames"] / clock.wall
        result["end_to_end_seconds"] = report["seconds"]
        cpu_ms["end_to_end"] = 1000.0 * clock.cpu / report["frames"]
    result["cpu_ms_per_frame"] = {k: round(v, 2) for k, v in cpu_ms.items()}
    result["cpu_cores"] = cpu_cores()
    result["end_to_end_fps_cpu_bound"] = result["cpu_cores"] * 1000.0 / cpu_ms["end_to_end"]
    result["end_to_end_over_cpu_bound"] = result["end_to_end_fps"] / result["end_to_end_fps_cpu_bound"]
    result["end_to_end_over_track_fps"] = result["end_to_end_fps"] / result["track_fps"]
    result["peak_rss_mb"] = peak_rss_mb()
    result["goals"] = {
        "end_to_end_fps >= 0.8 x end_to_end_fps_cpu_bound": result["end_to_end_over_cpu_bound"] >= 0.8,
        "end_to_end_fps >= 0.45 x track_fps": result["end_to_end_over_track_fps"] >= 0.45,
        "render auto >= 0.9 x off": result["render_auto_over_off"] >= 0.9,
        "retarget + wrinkle <= 1 ms": result["retarget_ms_per_frame"] + result["wrinkle_ms_per_frame"] <= 1.0,
    }
    result["machine"] = machine_description()
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in result.items()}


def _render_rounds(rig, animation, options, progress: bool = True) -> tuple[list[np.ndarray], dict, float]:
    """Render fps per wrinkle driver, interleaved (see the module doc). Returns up to 30
    ``auto`` frames (for the encode figure), the figures, and the ``auto`` driver's
    processor time per frame (ms)."""
    drivers = ("off", "auto", "dynamic")
    n_render = min(animation.n_frames, RENDER_FRAMES_MAX)
    base = run_render_options(options)
    poses = avatar_head_poses(rig, animation.head_pose, base.fov_y_degrees)
    states = [FrameState(bone_positions=animation.bone_positions[i], blend_weights=animation.blend_weights[i],
                         head_pose=poses[i], influences=animation.influences[i],
                         zone_weights=animation.zone_weights[i],
                         eye_rotation=None if animation.eye_rotation is None else animation.eye_rotation[i])
              for i in range(n_render)]
    fps: dict[str, list[float]] = {d: [] for d in drivers}
    cpu: dict[str, float] = dict.fromkeys(drivers, 0.0)
    rendered: list[np.ndarray] = []
    renderers = {}
    try:
        for d in drivers:
            renderers[d] = Renderer.create_from_options(rig, replace(base, wrinkles=d))
            renderers[d].render(states[0])  # compile + first-use costs out of the timing
        bar = tqdm(total=RENDER_ROUNDS * len(drivers), desc="render rounds", disable=not progress, leave=False)
        for k in range(RENDER_ROUNDS):
            for j in range(len(drivers)):
                d = drivers[(j + k) % len(drivers)]  # rotate who goes first
                with _Clock() as clock:
                    for state in states:
                        image = renderers[d].render(state)
                        if d == "auto" and len(rendered) < 30:
                            rendered.append(image)
                fps[d].append(n_render / clock.wall)
                cpu[d] += clock.cpu
                bar.update(1)
        bar.close()
        gl = renderers["off"].gl_renderer
    finally:
        for r in renderers.values():
            r.close()
    figures = {f"render_fps_wrinkles_{d}": float(np.median(fps[d])) for d in drivers}
    figures["render_auto_over_off"] = float(np.median(np.array(fps["auto"]) / np.array(fps["off"])))
    figures["render_rounds_fps"] = {d: [round(v, 2) for v in fps[d]] for d in drivers}
    figures["render_antialias"] = "fxaa" if base.fxaa else f"msaa{base.samples}" if base.samples > 1 else "none"
    figures["gl_renderer"] = gl
    return rendered, figures, 1000.0 * cpu["auto"] / (RENDER_ROUNDS * n_render)


def machine_description() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical CPUs, {platform.system()} {platform.release()}"


# ---- calibration: a range-of-motion take, tracked and learned ------------------------------
CALIBRATE_GOAL_SECONDS = 10.0  # per 30 s of take, on 2 cores (issue 32)


def rom_actor(folder: str | os.PathLike):
    """The built-in avatar as a third-party ARKit character (written to ``folder`` and
    loaded back as any user's .glb is): an actor ``synth --rom`` can perform with."""
    path = Path(folder) / "avatar_arkit.glb"
    export_arkit_character(default_avatar(), path)
    return load_character(path)


def calibration_bench(size: int = 512, progress: bool = True, seed: int = 0) -> dict:
    """Time ``capture2face calibrate`` (:func:`~capture2face.pipeline.calibration.learn_calibration`:
    track the take, then learn) on the protocol's take at ``size`` x ``size``.

    Returns:
        ``take_frames``, ``take_seconds``, ``synth_seconds``, ``calibrate_seconds`` (wall),
        ``calibrate_seconds_per_30s``, ``cpu_seconds`` (all threads and workers),
        ``steps_found``, ``cpu_cores``, ``goals`` and ``machine``.
    """
    with tempfile.TemporaryDirectory(prefix="capture2face-bench-") as tmp:
        take = Path(tmp) / "rom.mp4"
        t = time.perf_counter()
        truth = synthesize(take, SynthOptions(size=size, rom=True, seed=seed), progress=progress,
                           actor=rom_actor(tmp)).truth
        synth_s = time.perf_counter() - t
        frames, fps = truth.n_frames, float(truth.fps)
        with _Clock() as clock:
            calibration = learn_calibration(take, RunOptions().track, progress=progress)
    per_30 = clock.wall * 30.0 / (frames / fps)
    result = {
        "size": int(size), "take_frames": int(frames), "take_seconds": frames / fps, "synth_seconds": synth_s,
        "calibrate_seconds": clock.wall, "calibrate_seconds_per_30s": per_30, "cpu_seconds": clock.cpu,
        "steps_found": sum(s.found for s in calibration.steps), "steps": len(calibration.steps),
        "cpu_cores": cpu_cores(),
        "goals": {f"calibrate a 30 s take <= {CALIBRATE_GOAL_SECONDS:g} s": per_30 <= CALIBRATE_GOAL_SECONDS},
        "machine": machine_description(),
    }
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in result.items()}


# ---- memory: peak RSS against clip length ------------------------------------------------
def loop_clip(source: str | os.PathLike, dest: str | os.PathLike, seconds: float) -> int:
    """Write ``dest`` by repeating ``source``'s compressed packets until it lasts at least
    ``seconds`` (a remux: no decoding or encoding, so a 10-minute clip takes seconds).

    ``source`` must start with a keyframe (every clip this project writes does).
    Returns the number of frames written.
    """
    import av

    with av.open(str(source)) as inp:
        stream = inp.streams.video[0]
        packets = [(bytes(p), p.pts, p.dts, p.duration, p.is_keyframe) for p in inp.demux(stream) if p.size]
        if not packets or not packets[0][4]:
            raise CaptureError(f"{source}: cannot loop a clip that does not start with a keyframe")
        tb = stream.time_base
        first = min(p[1] for p in packets)
        span = max(p[1] + (p[3] or 0) for p in packets) - first
        loops = max(1, int(np.ceil(seconds / float(span * tb))))
        with atomic_path(dest) as tmp, av.open(str(tmp), "w") as out:
            ostream = out.add_stream_from_template(stream)
            for k in range(loops):
                for data, pts, dts, duration, key in packets:
                    packet = av.Packet(data)
                    packet.stream = ostream
                    packet.time_base = tb
                    packet.pts, packet.dts = pts + k * span, dts + k * span
                    packet.duration, packet.is_keyframe = duration, key
                    out.mux(packet)
    return loops * len(packets)


def run_peak_rss(clip: str | os.PathLike, out_dir: str | os.PathLike, size: int) -> tuple[float, float]:
    """Run ``capture2face run`` on ``clip`` in a child process; returns its peak RSS (MiB,
    from ``wait4``: that child alone) and its wall time (s)."""
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    cmd = [sys.executable, "-m", "capture2face", "-q", "run", os.fspath(clip), "-o", os.fspath(out_dir),
           "--size", str(size)]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    except BaseException:
        proc.kill()
        raise
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode != 0:
        raise CaptureError(f"run on {clip} failed ({proc.returncode}): {err.strip()[-300:]}")
    return usage.ru_maxrss / 1024.0, time.perf_counter() - t


def memory_check(long_seconds: float = 600.0, short_seconds: float = 10.0, size: int = 512,
                 progress: bool = True) -> dict:
    """Peak RSS of ``capture2face run`` on a ``long_seconds`` clip vs a ``short_seconds``
    one at the same size (both loops of one synthetic clip). The pipeline streams frames
    through bounded queues and keeps landmarks on disk, so only ~1.5 KB a frame (the
    Animation, the track's scores and poses) grows with length.

    Returns:
        ``short_peak_rss_mb``, ``long_peak_rss_mb``, ``ratio`` (long / short), the clip
        lengths in frames and the wall time of each run.
    """
    fps = 30.0
    with tempfile.TemporaryDirectory(prefix="capture2face-memory-") as tmp:
        tmp = Path(tmp)
        base = tmp / "base.mp4"
        synthesize(base, SynthOptions(frames=int(round(short_seconds * fps)), size=size, fps=fps, seed=1),
                   progress=progress)
        long_clip = tmp / "long.mp4"
        long_frames = loop_clip(base, long_clip, long_seconds)
        short_rss, short_s = run_peak_rss(base, tmp / "out", size)
        long_rss, long_s = run_peak_rss(long_clip, tmp / "out", size)
    return {
        "size": int(size),
        "short_frames": int(round(short_seconds * fps)), "long_frames": int(long_frames),
        "short_peak_rss_mb": round(short_rss, 1), "long_peak_rss_mb": round(long_rss, 1),
        "ratio": round(long_rss / short_rss, 3),
        "short_run_seconds": round(short_s, 1), "long_run_seconds": round(long_s, 1),
    }


def summary_line(result: dict) -> str:
    """One line: the bench's main figures and its goals met (or the memory check's peaks)."""
    if "goals" not in result:  # --memory-seconds
        return (f"peak RSS {result['short_peak_rss_mb']:.0f} MB for {result['short_frames']} frames, "
                f"{result['long_peak_rss_mb']:.0f} MB for {result['long_frames']} ({result['ratio']:.2f}x)")
    goals = result["goals"]
    missed = [name for name, met in goals.items() if not met]
    if "calibrate_seconds" in result:  # --calibration
        return (f"calibrate {result['calibrate_seconds']:.1f} s for a {result['take_seconds']:.0f} s take "
                f"({result['calibrate_seconds_per_30s']:.1f} s per 30 s on {result['cpu_cores']} cores), steps found "
                f"{result['steps_found']}/{result['steps']}; goals met {len(goals) - len(missed)}/{len(goals)}")
    return (f"end to end {result['end_to_end_fps']:.1f} fps ({result['end_to_end_over_cpu_bound']:.2f}x the "
            f"{result['cpu_cores']}-core CPU bound), track {result['track_fps']:.1f} fps, render auto "
            f"{result['render_fps_wrinkles_auto']:.1f} fps ({result['render_auto_over_off']:.2f}x off), retarget + "
            f"wrinkles {result['retarget_ms_per_frame'] + result['wrinkle_ms_per_frame']:.2f} ms/frame; "
            f"goals met {len(goals) - len(missed)}/{len(goals)}"
            + (f" (missed: {'; '.join(missed)})" if missed else ""))

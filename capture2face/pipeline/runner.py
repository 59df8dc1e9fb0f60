"""``capture2face run``: one clip in, an animated wrinkled character out.

Three passes over the clip, because retargeting needs the neutral frame, which is picked
from the whole clip:

1. decode + track (:func:`track_stage`; MediaPipe at its own speed, decoding prefetched;
   the landmarks go to files in the run's work folder, ``.work`` in the staging folder);
2. retarget in overlapping windows of frames (:func:`retarget_stage`; vectorized,
   milliseconds) and write the animation exports (:func:`export_stage`);
3. render + compose + encode (:func:`render_stage`): the GL thread (this one, which owns
   the context) renders the character and its wrinkle-influence view while worker
   threads decode the source again, compose compare.mp4 frames and run the two H.264
   encoders, all joined by bounded queues.

Memory does not grow with the clip's length beyond ~1.5 KB a frame (the Animation and the
track's per-frame scores and poses): whole-clip computations run window by window and
malloc is kept from fragmenting (:mod:`capture2face.runtime.heap`).

Every output is written into a hidden temporary folder whose files move into
``OUT/<clip stem>/`` only when all of them are complete (:mod:`capture2face.io.staging`), so
a failure or an interrupt (SIGINT, SIGTERM) leaves nothing half-written behind; only the
run's own files there are replaced (report.json's ``outputs`` say which), never a user's
file nor the source clip.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

from capture2face.character.landmark_sources import eye_facts, landmark_facts
from capture2face.errors import CaptureError, raise_if_interrupted
from capture2face.io.atomic import write_text_atomic
from capture2face.io.fingerprint import fingerprint
from capture2face.io.staging import check_output_folder, folder_name_problem, staged_folder
from capture2face.io.video_input import watch_damage
from capture2face.measures import clip_fidelity
from capture2face.pipeline.calibration import calibration_report, resolve_calibration
from capture2face.pipeline.options import CALIBRATION_FILE, OUTPUT_FILES, RunOptions, input_files, options_json
from capture2face.pipeline.preflight import preflight
from capture2face.pipeline.render_pass import render_stage
from capture2face.pipeline.report.html import write_report_html
from capture2face.pipeline.report.posters import poster_frames
from capture2face.pipeline.report.run import check_same_clip, track_warnings
from capture2face.pipeline.stages import (
    export_stage,
    retarget_stage,
    start_track_workers,
    track_stage,
)
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.cores import free_cores
from capture2face.runtime.heap import bound_heap, release_free_memory
from capture2face.runtime.log import collect_warnings, log
from capture2face.tracking.rest import actor_rest, rest_report


@contextlib.contextmanager
def _work_folder(staging: Path):
    """Scratch files of a run (the track's landmarks) in the staging folder, deleted
    before the folder becomes the output (and with it on failure)."""
    work = staging / ".work"
    work.mkdir()
    try:
        yield work
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _close_track_files(track) -> None:
    for name in ("landmarks_px", "landmarks_depth", "landmarks_head"):
        close = getattr(getattr(track, name), "close", None)
        if close is not None:
            close()


def _run_fidelity(track, animation, rig: FaceRig, name: str):
    """The run's :class:`~capture2face.measures.ClipFidelity`, or None (with a warning in the
    report) when it cannot be measured, e.g. a character without the measured landmarks."""
    if not np.any(np.asarray(track.presence, bool)):
        return None
    try:
        return clip_fidelity(track, animation, rig, name)
    except CaptureError as exc:
        log.warning("no expression-fidelity figures: %s", exc)
        return None


def run(clip: str | os.PathLike, out_dir: str | os.PathLike, options: RunOptions | None = None,
        progress: bool = True, name: str | None = None) -> dict:
    """Clip -> ``out_dir/<clip stem>/`` with avatar.mp4, compare.mp4, track.npz,
    animation.npz, animation.glb, livelink.csv, report.json and report.html (the report as
    a self-contained page: poster frames, curves, fidelity figures;
    :mod:`capture2face.pipeline.report`).

    Args:
        clip: the source video.
        out_dir: parent folder of the clip's output folder (created if needed).
        options: :class:`RunOptions`.
        progress: tqdm progress bars.
        name: output folder name (default: the clip's stem).
    Returns:
        The report (also written as report.json): frames, tracked_frames, fps, seconds
        per stage, warnings, outputs, fidelity (:meth:`ClipFidelity.figures
        <capture2face.measures.ClipFidelity.figures>`, None without a measurable face).
    Raises:
        CaptureError: unreadable clip, no face, bad character, output not writable, ...
            Nothing is left in ``out_dir`` then (nor on KeyboardInterrupt).
    """
    options = options or RunOptions()
    _check_folder_name(clip, name)
    bound_heap()  # memory flat whatever the clip's length (see capture2face.runtime.heap)
    t_start = time.perf_counter()
    workers = start_track_workers(clip, options)  # they start up while the checks run
    try:
        return _run(clip, out_dir, options, progress, name, workers, t_start)
    finally:
        if workers is not None:
            workers.close()


def _check_folder_name(clip, name: str | None) -> None:
    """The output folder's name (``--name``, else the clip's stem) is one a run can own."""
    folder = Path(clip).stem if name is None else name
    why = folder_name_problem(folder)
    if why:
        raise CaptureError(f"--name {folder!r}: {why}" if name is not None else
                           f"{clip}: the output folder's name {folder!r} {why}; give another with --name")


def _timed(fn, *args, **kwargs) -> float:
    """Call ``fn(*args, **kwargs)``; its wall seconds."""
    t = time.perf_counter()
    fn(*args, **kwargs)
    return time.perf_counter() - t


def _run(clip, out_dir, options: RunOptions, progress: bool, name: str | None, workers, t_start: float) -> dict:
    # Bad input fails here, before anything is written or tracked: options and limits, the
    # clip, the neutral frame, the face model, a drivable character, the GL context.
    with collect_warnings() as checked:  # the character's warnings (prepared or read back) are the run's too
        info, rig = preflight(clip, options, progress=progress)
    # What the result is made from (report.json's "inputs"; batch --resume compares them).
    inputs = {role: fingerprint(path) for role, path in input_files(clip, options).items()}
    final = Path(out_dir) / (name or Path(clip).stem)
    check_same_clip(final, inputs["clip"])  # day1/take.mp4 never silently replaces day2/take.mp4's
    seconds: dict[str, float] = {"checks": time.perf_counter() - t_start}  # the default avatar's first build too
    # Only the run's own files in ``final`` are replaced; the clip itself is never touched.
    outputs = [f for f in OUTPUT_FILES if (f != "compare.mp4" or options.compare)
               and (f != CALIBRATION_FILE or options.track.calibration is not None)]
    check_output_folder(final, outputs, OUTPUT_FILES, protect=[clip])
    with collect_warnings() as warnings, \
            staged_folder(final, OUTPUT_FILES, protect=[clip]) as tmp, _work_folder(tmp) as work:
        calibration = _calibration(options, progress, tmp, seconds)
        t = time.perf_counter()
        track = _track(clip, options, progress, work, workers, info, calibration)
        track.save(tmp / "track.npz")
        release_free_memory()
        seconds["track"] = time.perf_counter() - t
        raise_if_interrupted()

        t = time.perf_counter()
        animation = retarget_stage(track, rig, options.retarget)
        release_free_memory()
        seconds["retarget"] = time.perf_counter() - t
        raise_if_interrupted()

        kept = _render_and_export(clip, track, animation, rig, tmp, options, progress, seconds)
        release_free_memory()
        raise_if_interrupted()

        t = time.perf_counter()
        fidelity = _run_fidelity(track, animation, rig, final.name)  # reads the track's landmark files
        _close_track_files(track)
        seconds["fidelity"] = time.perf_counter() - t

        seconds["total"] = time.perf_counter() - t_start
        report = _report(clip, final, rig, track, info, options, outputs, seconds, checked + list(warnings),
                         fidelity, calibration)
        report["inputs"] = inputs
        # report.html shows the seconds up to here; report.json adds its own and the total.
        t = time.perf_counter()
        write_report_html(tmp / "report.html", report, track, animation,
                          tmp / ("compare.mp4" if options.compare else "avatar.mp4"), fidelity, kept)
        seconds["report_html"] = time.perf_counter() - t
        seconds["total"] = time.perf_counter() - t_start
        report["seconds"] = {k: round(v, 3) for k, v in seconds.items()}
        report["fps_processing"] = track.n_frames / seconds["total"]
        raise_if_interrupted()  # the last moment before the outputs replace the old ones
        write_text_atomic(tmp / "report.json", json.dumps(report, indent=2) + "\n")
    return report


def _calibration(options: RunOptions, progress: bool, tmp: Path, seconds: dict[str, float]):
    """The run's calibration (``--calibration``: loaded, or learned from its take), written
    as calibration.json among the outputs; None without one."""
    if options.track.calibration is None:
        return None
    t = time.perf_counter()
    calibration = resolve_calibration(options.track, progress)
    calibration.save(tmp / CALIBRATION_FILE)
    seconds["calibration"] = time.perf_counter() - t
    return calibration


def _track(clip, options: RunOptions, progress: bool, work: Path, workers, info, calibration=None):
    """Pass 1 (with ``calibration``: the track carries it), refusing a
    damaged clip unless ``options.allow_truncated``."""
    if calibration is not None:  # learned or loaded once, before tracking
        options = dataclasses.replace(options, track=dataclasses.replace(options.track, calibration=calibration))
    with watch_damage(clip) as damage:
        try:
            return track_stage(clip, options, progress, workdir=work, workers=workers, info=info)
        finally:
            if workers is not None:
                workers.close()
            # The decoder keeps the frames before any damage; a run would silently lose
            # the clip's tail, so that takes an explicit opt-in. (Checked even when
            # tracking failed: a damaged file is the cause to report.)
            if damage and not options.allow_truncated:
                raise CaptureError(damage[0].message)


def _render_and_export(clip, track, animation, rig: FaceRig, tmp: Path, options: RunOptions, progress: bool,
                       seconds: dict[str, float]) -> dict:
    """Pass 3 and the exports into ``tmp``; their seconds into ``seconds``. Returns the
    frames kept for report.html."""
    # The render pass starts as soon as the animation is solved. The exports need
    # nothing it makes: with cores to spare they are written beside it; on two cores,
    # which the render pass fills, after it (beside it they would gain nothing and
    # their transient memory, ~1.7 KB a frame, would add to the render pass's peak).
    beside = free_cores() > 2
    with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="capture2face-export") as pool:
        exported = (pool.submit(_timed, export_stage, rig, animation, tmp, track, character=options.character)
                    if beside else None)
        try:
            t = time.perf_counter()
            posters = [i for i, _ in poster_frames(animation, track.neutral_frame)]  # report.html's
            rendered = render_stage(clip, track, animation, rig, tmp, options, progress, keep_frames=posters)
            seconds["render_encode"] = time.perf_counter() - t
            seconds["render_gl"] = rendered["render_s"]
        except BaseException:
            if exported is not None:
                concurrent.futures.wait([exported])  # it writes into the staging folder: done first
            raise  # the render's error (an export error too would hide it)
        if exported is None:
            # The render pass's threads leave free but resident heap behind (~3 KB a
            # frame); handed back first, the exports' transient memory (~1.7 KB a frame)
            # rises from the post-render baseline instead of stacking on the render's peak.
            release_free_memory()
        seconds["export"] = exported.result() if exported is not None else \
            _timed(export_stage, rig, animation, tmp, track, character=options.character)
    return rendered["kept"]


def _report(clip, final: Path, rig: FaceRig, track, info, options: RunOptions, outputs: list[str],
            seconds: dict[str, float], warnings: list[str], fidelity, calibration=None) -> dict:
    """report.json's content (its seconds are updated once report.html is written); the
    ``calibration`` section only with one."""
    n = track.n_frames
    if calibration is not None:
        warnings = warnings + list(calibration.warnings)
    report = {
        "clip": os.fspath(clip),
        "output_dir": os.fspath(final),
        "character": rig.name,
        "character_landmarks": landmark_facts(rig),
        "character_eyes": eye_facts(rig),
        "wrinkles": options.render.wrinkles,
        "size": int(options.render.size),
        "frames": n,
        "tracked_frames": track.tracked_frames,
        "fps": float(track.fps),
        "source_size": [int(track.width), int(track.height)],
        "neutral_frame": int(track.neutral_frame),
        "rest": rest_report(actor_rest(track), list(track.blendshape_names)),
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
        "fps_processing": n / seconds["total"],
        "track_fps": n / seconds["track"],
        "warnings": list(dict.fromkeys(track_warnings(track, options) + warnings)),  # a file read twice says it once
        "outputs": outputs,  # the run's manifest (capture2face.io.staging)
        "options": options_json(options),
        "video": {"codec": info.codec, "rotation": info.rotation},
        "fidelity": fidelity.figures() if fidelity is not None else None,
    }
    if calibration is None:
        return report
    at = list(report).index("rest") + 1  # beside the rest it brings
    items = list(report.items())
    return dict(items[:at] + [("calibration", calibration_report(calibration))] + items[at:])

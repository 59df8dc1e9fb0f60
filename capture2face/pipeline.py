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
import json
import logging
import os
import threading
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from capture2face.errors import CaptureError, raise_if_interrupted
from capture2face.io.atomic import write_text_atomic
from capture2face.render.renderer import WRINKLE_DRIVERS
from capture2face.report_html import poster_frames, write_report_html
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.heap import bound_heap, release_free_memory

OUTPUT_FILES = ("avatar.mp4", "compare.mp4", "track.npz", "animation.npz", "animation.glb",
                "livelink.csv", "report.html", "report.json")
BUILTIN_CHARACTERS = ("default", "wide")

log = logging.getLogger("capture2face")


@dataclass
class RunOptions:
    """What ``run`` makes of a clip.

    Attributes:
        character: None (the default avatar), a built-in name ("default", "wide"), a
            FaceRig .npz (``FaceRig.save``), a .glb / .gltf (ARKit-named morphs are driven
            with no mapping; a mapping JSON beside it, ``<name>.json``, for face bones or
            other morph names), or a :class:`FaceRig`.
        wrinkles: wrinkle driver: auto (Dutreve bone masks), zones, dynamic, off.
        size: rendered frame size in pixels (square, even).
        neutral_frame: index of the neutral frame (None: picked automatically).
        face_model: MediaPipe ``face_landmarker.task`` (None: the default lookup).
        compare: also write compare.mp4.
        samples: MSAA samples of the renders; None: 4 on a GPU, and on a software GL
            (llvmpipe) 1 sample + an FXAA pass, whose edges look alike at ~55% of the cost.
        crf: H.264 quality of the videos (lower = better, larger).
        preset: x264 preset of the videos ("veryfast" encodes ~3x faster than "medium"
            at about the same size for rendered faces).
        queue_frames: frames buffered between overlapped stages.
        allow_truncated: process the frames before the damage of a truncated or
            corrupt clip (with a warning) instead of failing.
        audio: copy the clip's audio (if any) into avatar.mp4 and compare.mp4.
        faces: with several faces in view, the one that starts the track: "largest" or
            "center" (nearest the image centre); the one continuing it is followed.
        face: instead, the face with this index (0-based, left to right) in the first
            frame where more than ``face`` faces are seen, then followed.
        track_workers: MediaPipe landmarkers tracking segments of the clip at once, each
            in its own process (:mod:`capture2face.tracking.segments`); None: one per free
            core; 1: one. ``batch`` runs each clip with one when it runs clips in parallel.
    """

    character: Any = None
    wrinkles: str = "auto"
    size: int = 512
    neutral_frame: int | None = None
    face_model: str | os.PathLike | None = None
    compare: bool = True
    samples: int | None = None
    crf: int = 20
    preset: str = "veryfast"
    queue_frames: int = 8
    allow_truncated: bool = False
    audio: bool = True
    faces: str = "largest"
    face: int | None = None
    track_workers: int | None = None

    def validate(self) -> None:
        if self.wrinkles not in WRINKLE_DRIVERS:
            raise CaptureError(f"unknown wrinkle driver '{self.wrinkles}'; choose one of {', '.join(WRINKLE_DRIVERS)}")
        from capture2face.preflight import check_size

        check_size(self.size)  # even, 64..4096
        self.track_options().validate()  # faces, face, track_workers, neutral_frame

    def track_options(self):
        """The :class:`~capture2face.tracking.TrackOptions` of ``run``'s tracking."""
        from capture2face.tracking import TrackOptions

        return TrackOptions(face_model=self.face_model, neutral_frame=self.neutral_frame, faces=self.faces,
                            face=self.face, workers=self.track_workers)


# ---- character ------------------------------------------------------------------------
def load_character(character: Any = None, progress: bool = False) -> FaceRig:
    """The rig to animate (see :attr:`RunOptions.character`); ``progress``: a progress bar
    while a built-in avatar is built (the first use on a machine, then it is cached).

    Raises:
        CaptureError: missing, corrupt or unsupported character file.
    """
    if character is None:
        return builtin_avatar(None, progress)
    if isinstance(character, FaceRig):
        return character
    text = os.fspath(character)
    if text in BUILTIN_CHARACTERS and not Path(text).exists():
        return builtin_avatar(None if text == "default" else text, progress)
    path = Path(text)
    if not path.is_file():
        raise CaptureError(f"character {path}: no such file" if not path.exists()
                           else f"character {path}: not a file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            return FaceRig.load(path)
        if suffix in (".glb", ".gltf"):
            return _imported_character(path)
    except CaptureError as exc:
        # The readers turn a malformed file into CaptureError; anything else is a bug of
        # ours and keeps its traceback (--debug) instead of blaming the user's file.
        msg = str(exc)
        raise CaptureError(msg if msg.startswith(("character", str(path))) else f"character {path}: {msg}") from None
    raise CaptureError(f"character {path}: unsupported format '{suffix}'; "
                       "use a FaceRig .npz or a .glb with its mapping .json")


# The last .glb / .gltf character imported in this process, by _file_key: a batch (its
# check, then every clip run in this process) imports it and redoes its automatic
# wrinkles (2-6 s) once. Callers treat a FaceRig as read-only (as default_avatar's memo).
_IMPORTED: dict[tuple, tuple[FaceRig, list[str]]] = {}


def _file_key(path: Path) -> tuple:
    """(resolved path, mtime, size) of a file, or (path, None) where there is none."""
    try:
        st = path.stat()
    except OSError:
        return str(path.resolve()), None
    return str(path.resolve()), st.st_mtime_ns, st.st_size


def _imported_character(path: Path) -> FaceRig:
    """``path`` (.glb / .gltf) imported, with the mapping JSON beside it if any, and its
    automatic wrinkles; the same rig again while neither file changes."""
    mapping = path.with_suffix(".json")
    key = (_file_key(path), _file_key(mapping))
    if key in _IMPORTED:
        rig, said = _IMPORTED[key]
        for message in said:  # what the import warned, said again for this use
            log.warning("%s", message)
        return rig
    from capture2face.gltf import import_glb

    with _collect_warnings() as said:
        rig = with_automatic_wrinkles(import_glb(path, mapping if mapping.is_file() else None))
    _IMPORTED.clear()  # one character kept: a body .glb may be hundreds of MB
    _IMPORTED[key] = rig, list(said)
    return rig


def with_automatic_wrinkles(rig: FaceRig) -> FaceRig:
    """An ARKit morph character without face bones with its automatic wrinkle influences
    (:mod:`capture2face.rig.auto_wrinkles`: its front view tracked, feature points, poses
    from its morphs); any other rig as it is. Where its face cannot be found, the rig
    as it is, with a warning (it is still driven, without wrinkle influences)."""
    from capture2face.rig.arkit_names import drive_mode, is_automatic
    from capture2face.rig.auto_wrinkles import automatic_wrinkles

    try:
        if is_automatic(rig) or drive_mode(rig) != "arkit":
            return rig
    except CaptureError:
        return rig  # undrivable: the check before tracking says why
    try:
        return automatic_wrinkles(rig)
    except CaptureError as exc:
        log.warning("no automatic wrinkles: %s", exc)
        return rig


def builtin_avatar(variant: str | None = None, progress: bool = False) -> FaceRig:
    """:func:`~capture2face.rig.avatar.default_avatar`, with a progress bar (and an entry
    in the log) when it is not cached yet: its build takes ~5 s, once per machine and
    version (``run`` counts it in report.json's ``seconds["checks"]``)."""
    from capture2face.rig import avatar

    if avatar.is_cached(variant):
        return avatar.default_avatar(variant)
    from tqdm import tqdm

    log.info("building the %s avatar (first use; cached in %s)", variant or "default", avatar.cache_dir())
    t = time.perf_counter()
    with tqdm(total=1, disable=not progress, desc=f"building the {variant or 'default'} avatar (first use, "
              "then cached)", bar_format="{desc}: {elapsed}", leave=False) as bar:
        done = threading.Event()

        def tick() -> None:  # the elapsed time counts while the build runs
            while not done.wait(0.5):
                bar.refresh()

        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
        try:
            rig = avatar.default_avatar(variant)
        finally:
            done.set()
            ticker.join()
        bar.update(1)
    log.info("built the %s avatar in %.1f s", variant or "default", time.perf_counter() - t)
    return rig


# ---- stages (each callable on its own) ------------------------------------------------
def track_stage(clip: str | os.PathLike, options: RunOptions, progress: bool = True,
                workdir: str | os.PathLike | None = None, workers=None, info=None):
    """Pass 1: the clip's :class:`~capture2face.tracking.track.Track` (with ``workdir``,
    its landmarks stay in files there: memory does not grow with the clip's length;
    ``workers``: :func:`start_track_workers`' processes; ``info``: the clip's
    :func:`~capture2face.tracking.video.open_video` probe, if already made)."""
    from capture2face.tracking import track_clip

    return track_clip(clip, options.track_options(), progress=progress, workdir=workdir, workers=workers,
                      info=info)


def start_track_workers(clip: str | os.PathLike, options: RunOptions):
    """The segment-tracking processes ``run`` will use for ``clip``, started now so that
    their start-up (Python, MediaPipe, the model) overlaps the checks before tracking;
    None when the clip will be tracked by one landmarker (too short, ``--face``, one
    core, or a clip that does not open: the checks report that)."""
    from capture2face.tracking.segments import MIN_SEGMENT_FRAMES, SegmentWorkers
    from capture2face.tracking.video import open_video

    track = options.track_options()
    n = track.n_workers()
    if n < 2 or track.face is not None:
        return None
    try:
        frames = open_video(clip).n_frames
    except CaptureError:
        return None
    k = min(n, frames // MIN_SEGMENT_FRAMES)
    return SegmentWorkers(k - 1, track.landmarker_options()) if k >= 2 else None


def retarget_stage(track, rig: FaceRig):
    """Pass 2: the :class:`~capture2face.retarget.animation.Animation` of ``rig``."""
    from capture2face.retarget import RetargetOptions, retarget

    return retarget(track, rig, RetargetOptions())


def export_stage(rig: FaceRig, animation, folder: str | os.PathLike, track=None, character: Any = None) -> None:
    """animation.npz, animation.glb and livelink.csv into ``folder`` (``track``: the
    clip's Track, whose MediaPipe scores fill Live Link columns the rig has no morph for;
    None uses the animation's copy of them). ``character``: the :attr:`RunOptions.character`
    the rig came from; a user's ARKit .glb gets its own file back, animated
    (:mod:`capture2face.gltf.character`), any other rig the FaceRig's export."""
    from capture2face.export.livelink import write_livelink_csv
    from capture2face.rig.arkit_names import drive_mode
    from capture2face.gltf import export_glb

    folder = Path(folder)
    animation.save(folder / "animation.npz")
    source = _character_file(character)
    if source is not None and drive_mode(rig) == "arkit":
        from capture2face.gltf.character import export_character_animation

        export_character_animation(source, rig, animation, folder / "animation.glb")
    else:
        export_glb(rig, folder / "animation.glb", animation=animation)
    write_livelink_csv(animation, track, folder / "livelink.csv")


def _character_file(character: Any) -> Path | None:
    """The .glb / .gltf a character option names, or None (built-in, .npz, a FaceRig)."""
    if character is None or isinstance(character, FaceRig):
        return None
    path = Path(os.fspath(character))
    return path if path.suffix.lower() in (".glb", ".gltf") and path.is_file() else None


def avatar_head_poses(rig: FaceRig, head_pose: np.ndarray, fov_y_degrees: float) -> np.ndarray:
    """(F, 4, 4) camera poses for the character: the tracked head rotation, with the face
    kept centred and framed (the source's camera distance means nothing for the rig).

    Args:
        head_pose: (F, 4, 4) tracked head -> camera transforms.
    """
    from capture2face.render.camera import face_centre_and_height, framing_pose

    centre = face_centre_and_height(rig)[0]
    # framing_pose without rotation puts the face centre at (0, 0, -distance); keep it
    # there whatever the rotation.
    target = framing_pose(rig, fov_y_degrees=fov_y_degrees)[:3, 3] + centre
    rot = np.asarray(head_pose, np.float64)[:, :3, :3]
    if getattr(rig, "head_weights", None) is not None:
        # The head joint turns (avatar_head_rotations), the camera and the body stay.
        rot = np.broadcast_to(np.eye(3), rot.shape)
    poses = np.tile(np.eye(4), (len(rot), 1, 1))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = target - rot @ centre
    return poses


def avatar_head_rotations(rig: FaceRig, head_pose: np.ndarray) -> np.ndarray | None:
    """(F, 3, 3) float32 head-joint rotations for a character with a head joint
    (``FaceRig.head_weights``; :attr:`FrameState.head_rotation
    <capture2face.render.renderer.FrameState.head_rotation>`), else None: the head
    rotation turns the whole character (:func:`avatar_head_poses`)."""
    if getattr(rig, "head_weights", None) is None:
        return None
    return np.ascontiguousarray(np.asarray(head_pose, np.float32)[:, :3, :3])


def run_render_options(options: RunOptions):
    """The :class:`~capture2face.render.RenderOptions` of ``run``'s character view (with
    ``compare``, its influence view comes out of the same draw)."""
    from capture2face.render import RenderOptions
    from capture2face.render.context import software_gl

    samples, fxaa = options.samples, False
    if samples is None:
        fxaa = software_gl()
        samples = 1 if fxaa else 4
    return RenderOptions(size=int(options.size), wrinkles=options.wrinkles, samples=int(samples), fxaa=fxaa,
                         influence_output=bool(options.compare))


def encoder_threads(software_gl: bool, cores: int | None = None) -> int:
    """x264 threads for each of ``run``'s two encoders. A software rasterizer (llvmpipe
    runs one thread per core) and small machines: one each, in threads of their own (x264's
    pool would take the cores the rasterizer needs). With a GPU drawing, the cores beyond
    the GL thread, decoding and compositing encode (x264 alone does ~150 fps at 512x512
    on one core, and run's compare.mp4 is three frames wide)."""
    from capture2face.tracking.segments import free_cores

    cores = free_cores() if cores is None else int(cores)
    if software_gl or cores <= 4:
        return 1
    return max(1, min(8, (cores - 2) // 2))


def render_stage(clip: str | os.PathLike, track, animation, rig: FaceRig, folder: str | os.PathLike,
                 options: RunOptions, progress: bool = True, keep_frames=()) -> dict:
    """Pass 3: avatar.mp4 and compare.mp4 into ``folder``, stages overlapped.

    One draw per frame gives both the character and its wrinkle-influence view (a second
    colour attachment); the GL thread only draws and reads back, while worker threads
    decode the source again, compose compare.mp4 frames and run the two H.264 encoders.

    Args:
        keep_frames: indices of frames to hand back as images (report.html's poster
            frames): compare.mp4's frames, or avatar.mp4's without ``options.compare``.
    Returns:
        ``{"render_s": GL thread busy seconds, "frames": n, "kept": {index: (H, W, 3) RGB}}``.
    """
    from tqdm import tqdm

    from capture2face.compose import SourceFitter, compare_frame
    from capture2face.render import FrameState, Renderer
    from capture2face.render.context import software_gl
    from capture2face.render.video import VideoWriter
    from capture2face.runtime.overlap import StageGroup
    from capture2face.tracking.video import iter_frames

    folder = Path(folder)
    n = animation.n_frames
    size = int(options.size)
    fps = float(track.fps)
    render_opts = run_render_options(options)
    poses = avatar_head_poses(rig, animation.head_pose, render_opts.fov_y_degrees).astype(np.float32)
    turns = avatar_head_rotations(rig, animation.head_pose)
    fitter = SourceFitter(track.width, track.height, size)
    q = max(2, int(options.queue_frames))
    threads = encoder_threads(software_gl())
    keep = {int(i) for i in keep_frames}
    kept: dict[int, np.ndarray] = {}
    # The source's frame times (a variable-rate clip keeps them) and its audio.
    times = np.asarray(track.times[:n], np.float64)
    audio_from = clip if options.audio else None

    def encode_avatar(frames) -> None:
        with VideoWriter(folder / "avatar.mp4", fps, (size, size), crf=options.crf, preset=options.preset,
                         threads=threads, times=times, audio_from=audio_from) as out:
            for frame in frames:
                out.write(frame)

    def decode_source(sink) -> None:
        for _, rgb in iter_frames(clip, max_frames=n):
            sink.put(rgb)
        sink.close()

    def encode_compare(panels, sources) -> None:
        src = iter(sources)
        with VideoWriter(folder / "compare.mp4", fps, (3 * size, size), crf=options.crf,
                         preset=options.preset, threads=threads, times=times, audio_from=audio_from) as out:
            for i, (avatar, heat) in enumerate(panels):
                frame = compare_frame(fitter, next(src, None), track.landmarks_px[i], bool(track.presence[i]),
                                      avatar, heat)
                out.write(frame)
                if i in keep:
                    kept[i] = frame
            for _ in src:  # drain, so the decoder is never left blocked
                pass

    busy = 0.0
    with StageGroup() as group, contextlib.ExitStack() as stack:
        avatar_q = group.channel(q)
        group.spawn("encode-avatar", encode_avatar, avatar_q)
        if options.compare:
            source_q, panel_q = group.channel(q), group.channel(q)
            group.spawn("decode", decode_source, source_q)
            group.spawn("encode-compare", encode_compare, panel_q, source_q)
        renderer = stack.enter_context(Renderer.create_from_options(rig, render_opts))
        bar = stack.enter_context(tqdm(total=n, disable=not progress, unit="frame", desc="rendering", leave=False))
        for i in range(n):
            raise_if_interrupted()
            t0 = time.perf_counter()
            state = FrameState(
                bone_positions=animation.bone_positions[i], blend_weights=animation.blend_weights[i],
                head_pose=poses[i], influences=animation.influences[i], zone_weights=animation.zone_weights[i],
                head_rotation=None if turns is None else turns[i],
                eye_rotation=None if animation.eye_rotation is None else animation.eye_rotation[i],
            )
            if options.compare:
                image, heat = renderer.render_with_influence(state)
            else:
                image = renderer.render(state)
            busy += time.perf_counter() - t0
            if i in keep and not options.compare:
                kept[i] = image.copy()
            avatar_q.put(image)
            if options.compare:
                panel_q.put((image, heat))
            bar.update(1)
        avatar_q.close()
        if options.compare:
            panel_q.close()
    return {"render_s": busy, "frames": n, "kept": kept}


# ---- outputs ---------------------------------------------------------------------------
def outputs_complete(folder: str | os.PathLike) -> bool:
    """True when ``folder`` holds a finished run: report.json and every output it lists."""
    folder = Path(folder)
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    names = report.get("outputs") or []
    return bool(names) and all((folder / name).is_file() and (folder / name).stat().st_size > 0 for name in names)


class _WarningLog(logging.Handler):
    """Collects the ``capture2face`` logger's warnings during a run for report.json."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


@contextlib.contextmanager
def _collect_warnings():
    handler = _WarningLog()
    log.addHandler(handler)
    try:
        yield handler.messages
    finally:
        log.removeHandler(handler)


def _track_warnings(track, options: RunOptions | None = None) -> list[str]:
    out = []
    missing = track.n_frames - track.tracked_frames
    if missing:
        out.append(f"no face in {missing} of {track.n_frames} frames ({track.n_gaps} gaps); "
                   "short gaps are interpolated, longer ones hold the last pose")
    if track.n_long_gaps:
        out.append(f"{track.n_long_gaps} gaps longer than the interpolation limit hold the last pose")
    if track.n_faces_max > 1:
        face, faces = (options.face, options.faces) if options is not None else (None, "largest")
        start = (f"face {face} from the left" if face is not None
                 else "the face nearest the centre" if faces == "center" else "the largest face")
        out.append(f"{track.n_faces_max} faces in view (the most seen at once); tracked: {start} at the start, "
                   "then the one continuing the track (choose with --face N or --faces largest|center)")
    return out


def _options_json(options: RunOptions) -> dict:
    out = {}
    for f in fields(options):
        v = getattr(options, f.name)
        if isinstance(v, FaceRig):
            v = v.name
        elif isinstance(v, os.PathLike):
            v = os.fspath(v)
        out[f.name] = v
    return out


@contextlib.contextmanager
def _work_folder(staging: Path):
    """Scratch files of a run (the track's landmarks) in the staging folder, deleted
    before the folder becomes the output (and with it on failure)."""
    import shutil

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
    """The run's :class:`~capture2face.fidelity.ClipFidelity`, or None (with a warning in the
    report) when it cannot be measured, e.g. a character without the measured landmarks."""
    from capture2face.fidelity import clip_fidelity

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
    :mod:`capture2face.report_html`).

    Args:
        clip: the source video.
        out_dir: parent folder of the clip's output folder (created if needed).
        options: :class:`RunOptions`.
        progress: tqdm progress bars.
        name: output folder name (default: the clip's stem).
    Returns:
        The report (also written as report.json): frames, tracked_frames, fps, seconds
        per stage, warnings, outputs, fidelity (:meth:`ClipFidelity.figures
        <capture2face.fidelity.ClipFidelity.figures>`, None without a measurable face).
    Raises:
        CaptureError: unreadable clip, no face, bad character, output not writable, ...
            Nothing is left in ``out_dir`` then (nor on KeyboardInterrupt).
    """
    options = options or RunOptions()
    bound_heap()  # memory flat whatever the clip's length (see capture2face.runtime.heap)
    t_start = time.perf_counter()
    workers = start_track_workers(clip, options)  # they start up while the checks run
    try:
        return _run(clip, out_dir, options, progress, name, workers, t_start)
    finally:
        if workers is not None:
            workers.close()


def _timed(fn, *args, **kwargs) -> float:
    """Call ``fn(*args, **kwargs)``; its wall seconds."""
    t = time.perf_counter()
    fn(*args, **kwargs)
    return time.perf_counter() - t


def _run(clip, out_dir, options: RunOptions, progress: bool, name: str | None, workers, t_start: float) -> dict:
    from capture2face.io.staging import check_output_folder, staged_folder
    from capture2face.preflight import preflight
    from capture2face.tracking.segments import free_cores
    from capture2face.tracking.video import watch_damage

    # Bad input fails here, before anything is written or tracked: options and limits, the
    # clip, the neutral frame, the face model, a drivable character, the GL context.
    info, rig = preflight(clip, options, progress=progress)
    final = Path(out_dir) / (name or Path(clip).stem)
    seconds: dict[str, float] = {"checks": time.perf_counter() - t_start}  # the default avatar's first build too
    # Only the run's own files in ``final`` are replaced; the clip itself is never touched.
    outputs = [f for f in OUTPUT_FILES if f != "compare.mp4" or options.compare]
    check_output_folder(final, outputs, OUTPUT_FILES, protect=[clip])
    with _collect_warnings() as warnings, \
            staged_folder(final, OUTPUT_FILES, protect=[clip]) as tmp, _work_folder(tmp) as work:
        t = time.perf_counter()
        with watch_damage(clip) as damage:
            try:
                track = track_stage(clip, options, progress, workdir=work, workers=workers, info=info)
            finally:
                if workers is not None:
                    workers.close()
                # The decoder keeps the frames before any damage; a run would silently lose
                # the clip's tail, so that takes an explicit opt-in. (Checked even when
                # tracking failed: a damaged file is the cause to report.)
                if damage and not options.allow_truncated:
                    raise CaptureError(damage[0].message)
        track.save(tmp / "track.npz")
        release_free_memory()
        seconds["track"] = time.perf_counter() - t
        raise_if_interrupted()

        t = time.perf_counter()
        animation = retarget_stage(track, rig)
        release_free_memory()
        seconds["retarget"] = time.perf_counter() - t
        raise_if_interrupted()

        # The render pass starts as soon as the animation is solved. The exports need
        # nothing it makes: with cores to spare they are written beside it; on two cores,
        # which the render pass fills, after it (beside it they would gain nothing and
        # their transient memory, ~1.7 KB a frame, would add to the render pass's peak).
        beside = free_cores() > 2
        with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="capture2face-export") as pool:
            exported = (pool.submit(_timed, export_stage, rig, animation, tmp, track,
                                     character=options.character)
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
        release_free_memory()
        raise_if_interrupted()

        t = time.perf_counter()
        fidelity = _run_fidelity(track, animation, rig, final.name)  # reads the track's landmark files
        _close_track_files(track)
        seconds["fidelity"] = time.perf_counter() - t

        seconds["total"] = time.perf_counter() - t_start
        n = track.n_frames
        report = {
            "clip": os.fspath(clip),
            "output_dir": os.fspath(final),
            "character": rig.name,
            "wrinkles": options.wrinkles,
            "size": int(options.size),
            "frames": n,
            "tracked_frames": track.tracked_frames,
            "fps": float(track.fps),
            "source_size": [int(track.width), int(track.height)],
            "neutral_frame": int(track.neutral_frame),
            "seconds": {k: round(v, 3) for k, v in seconds.items()},
            "fps_processing": n / seconds["total"],
            "track_fps": n / seconds["track"],
            "warnings": _track_warnings(track, options) + list(warnings),
            "outputs": outputs,  # the run's manifest (capture2face.io.staging)
            "options": _options_json(options),
            "video": {"codec": info.codec, "rotation": info.rotation},
            "fidelity": fidelity.figures() if fidelity is not None else None,
        }
        # report.html shows the seconds up to here; report.json adds its own and the total.
        t = time.perf_counter()
        write_report_html(tmp / "report.html", report, track, animation,
                          tmp / ("compare.mp4" if options.compare else "avatar.mp4"), fidelity, rendered["kept"])
        seconds["report_html"] = time.perf_counter() - t
        seconds["total"] = time.perf_counter() - t_start
        report["seconds"] = {k: round(v, 3) for k, v in seconds.items()}
        report["fps_processing"] = n / seconds["total"]
        raise_if_interrupted()  # the last moment before the outputs replace the old ones
        write_text_atomic(tmp / "report.json", json.dumps(report, indent=2) + "\n")
    return report

"""Many clips at once: ``capture2face batch``.

Clips run in parallel, each in a worker process of its own (MediaPipe and the GL context
are per process; a fresh process per clip also returns its memory). One failing clip
never stops the others: its error is recorded and the batch goes on. ``OUT/batch_report.json``
is rewritten (atomically) after every clip, so an interrupted batch still says what got
done, and ``resume=True`` skips the clips whose outputs are complete and were made with the
same options from the same files (a clip whose report.json options differ, or whose clip,
character or mapping file changed content, is run again, the entry saying why).
The report keeps the entries of an earlier batch into the same folder for clips not in
this batch (marked ``"earlier": true``); this batch's entries replace theirs.

With ``ray_address`` the clips become Ray tasks (``pip install capture2face[ray]``):
``"local"`` starts a local Ray instance, ``"auto"`` or ``"ray://host:10001"`` joins a
cluster whose workers have capture2face installed and can read the input paths. The
cluster is joined before anything is written; an address where nothing listens or
answers fails in one line within :data:`RAY_CONNECT_S` seconds.
"""

from __future__ import annotations

import atexit
import codecs
import contextlib
import dataclasses
import glob
import json
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from tqdm import tqdm

from capture2face.errors import CaptureError, install_process_defaults
from capture2face.io.atomic import write_text_atomic
from capture2face.io.fingerprint import changes, fingerprint
from capture2face.io.paths import ERRORS as PATH_ERRORS
from capture2face.io.staging import check_writable
from capture2face.pipeline import RunOptions, options_json, outputs_complete, run
from capture2face.pipeline.calibration import check_calibration, is_calibration_file, learn_calibration
from capture2face.pipeline.options import input_files
from capture2face.pipeline.preflight import check_gl, check_shared
from capture2face.runtime.cores import free_cores
from capture2face.runtime.log import warnings_to_stderr

VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm", ".mpg", ".mpeg", ".wmv", ".flv")
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".webp", ".bmp", ".tif", ".tiff")
NEUTRAL_SUFFIX = ".neutral"  # CLIP.neutral.jpg / CLIP.neutral.mp4 beside CLIP.mp4: its rest take
ROM_SUFFIX = ".rom"  # CLIP.rom.mp4 / CLIP.rom.json beside CLIP.mp4: its actor's calibration
_QUOTES = "\"'"  # a list line's names may be quoted
LIST_EXTENSIONS = (".txt", ".lst")
REPORT_NAME = "batch_report.json"
_GLOB_CHARS = set("*?[")
_MAX_ATTEMPTS = 2  # a clip whose worker process dies twice is marked failed
_STOP_S = 15.0  # a clip's process that has not ended this long after its result or SIGTERM is killed
RAY_CONNECT_S = 10.0  # --ray HOST:PORT: joined within this (the command's checks before it included: 15 s)


@dataclasses.dataclass
class BatchClip:
    """One input clip, the output folder name it gets (``OUT/<name>/``), its rest take
    (an image or a clip of the actor at rest) and its calibration (``rom``: a
    range-of-motion take or an actor.json; ``learned``: the take's ActorCalibration once the
    batch learned it), if any."""

    path: str
    name: str
    neutral: str | None = None
    rom: str | None = None
    learned: Any = None


def expand_inputs(inputs: Iterable[str | os.PathLike]) -> list[BatchClip]:
    """Clips from folders (their video files, sorted, not recursive), glob patterns, list
    files (``.txt``/``.lst``: one clip per line, paths relative to the list; see
    :func:`read_list`) and plain paths. A path that does not exist is kept: the batch reports it as
    failed rather than silently dropping it.

    Each clip's rest take: a list line's second column (after a tab or `` | ``), else a
    sidecar ``CLIP.neutral.<image or video extension>`` beside it; its calibration: a
    sidecar ``CLIP.rom.<video extension>`` or ``CLIP.rom.json``; sidecars are never
    clips of their own.

    Output names are the clip stems; clips sharing a stem get their parent folder's name
    prefixed (``a/take.mp4`` -> ``a_take``, ``b/take.mp4`` -> ``b_take``).

    Raises:
        CaptureError: nothing to process.
    """
    paths: list[Path] = []
    listed: dict[Path, Path] = {}  # clip -> the rest take its list line names
    for item in inputs:
        text = os.fspath(item)
        p = Path(text)
        if p.is_dir():
            paths += sorted(c for c in p.iterdir() if c.is_file() and c.suffix.lower() in VIDEO_EXTENSIONS
                            and not _is_sidecar(c))
        elif _GLOB_CHARS & set(text) and not p.exists():
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise CaptureError(f"no file matches {text}")
            paths += [Path(m) for m in matches if not Path(m).is_dir() and not _is_sidecar(Path(m))]
        elif p.is_file() and p.suffix.lower() in LIST_EXTENSIONS:
            for clip, neutral in read_list(p):
                paths.append(p.parent / clip)  # an absolute path stays itself
                if neutral:
                    listed[paths[-1]] = p.parent / neutral
        else:
            paths.append(p)
    seen: set[Path] = set()
    unique = []
    for p in paths:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    if not unique:
        raise CaptureError("no clips found in " + " ".join(os.fspath(i) for i in inputs))
    stems: dict[str, int] = {}
    for p in unique:
        stems[p.stem] = stems.get(p.stem, 0) + 1
    clips = []
    used: set[str] = set()
    for p in unique:
        name = p.stem if stems[p.stem] == 1 else f"{p.resolve().parent.name}_{p.stem}"
        base, k = name, 2
        while name in used:
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        neutral = listed.get(p) or _sidecar(p)
        rom = _rom_sidecar(p)
        clips.append(BatchClip(str(p), name, None if neutral is None else str(neutral),
                               None if rom is None else str(rom)))
    return clips


def read_list(path: Path) -> list[tuple[str, str | None]]:
    """A list file's entries: (clip, its rest take or None), as the lines name them.

    UTF-8, with or without the BOM Windows editors write (UTF-16 with its BOM too); a name
    that is not UTF-8 (Latin-1 bytes) still names its file (surrogateescape)."""
    data = path.read_bytes()
    if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        text = data.decode("utf-16", errors="surrogateescape")
    else:
        text = data.decode("utf-8-sig", errors="surrogateescape")
    return [entry for line in text.splitlines() if (entry := _list_entry(line)) is not None]


def _list_entry(line: str) -> tuple[str, str | None] | None:
    """A list file's line -> (clip, its rest take or None); None for a blank or comment line.

    A comment starts the line or follows whitespace (``take#2.mp4`` is a name); the rest
    take follows a tab or `` | ``; a name in quotes (``"take 1.mp4"``, ``'a | b.mp4'``)
    keeps what they hold, ``#`` and ``|`` included."""
    cut, sep, quote = len(line), None, None
    for i, c in enumerate(line):
        after_blank = i == 0 or line[i - 1].isspace()
        if quote is not None:
            quote = None if c == quote else quote
        elif c in _QUOTES and (after_blank or line[i - 1] == "|") and c in line[i + 1:]:
            quote = c  # opens a quoted name (an apostrophe inside a name does not)
        elif c == "#" and after_blank:
            cut = i
            break
        elif sep is None and (c == "\t" or line.startswith(" | ", i)):
            sep = (i, 1 if c == "\t" else 3)
    if sep is None:
        clip, neutral = _unquoted(line[:cut]), None
    else:
        clip, neutral = _unquoted(line[:sep[0]]), _unquoted(line[sep[0] + sep[1]:cut]) or None
    if not clip:
        return None
    return clip, neutral


def _unquoted(text: str) -> str:
    """``text`` without its blanks around and the quotes it is wrapped in, if any."""
    text = text.strip()
    if len(text) >= 2 and text[0] in _QUOTES and text[-1] == text[0]:
        return text[1:-1]
    return text


def _is_sidecar(path: Path) -> bool:
    return path.stem.lower().endswith((NEUTRAL_SUFFIX, ROM_SUFFIX))


def _rom_sidecar(clip: Path) -> Path | None:
    """``CLIP.rom.json`` or ``CLIP.rom.<video extension>`` beside ``clip``, if there is one."""
    for ext in (".json",) + VIDEO_EXTENSIONS:
        for candidate in (clip.with_name(clip.stem + ROM_SUFFIX + ext),
                          clip.with_name(clip.stem + ROM_SUFFIX + ext.upper())):
            if candidate.is_file():
                return candidate
    return None


def _sidecar(clip: Path) -> Path | None:
    """``CLIP.neutral.<ext>`` beside ``clip``, if there is one."""
    for ext in IMAGE_EXTENSIONS + VIDEO_EXTENSIONS:
        for candidate in (clip.with_name(clip.stem + NEUTRAL_SUFFIX + ext),
                          clip.with_name(clip.stem + NEUTRAL_SUFFIX + ext.upper())):
            if candidate.is_file():
                return candidate
    return None


def clip_options(clip: BatchClip, options: Any) -> Any:
    """``options`` for one clip: with its calibration (``clip.rom``, or what the batch
    learned from it) unless the batch gives one for every clip, and its rest take
    (``neutral_image`` or ``neutral_clip`` by its extension) unless the batch gives a rest."""
    track = options.track
    changes: dict[str, Any] = {}
    if track.calibration is None and clip.rom is not None:
        changes["calibration"] = clip.learned if clip.learned is not None else clip.rom
    rest_given = any(getattr(track, k) is not None for k in ("neutral_frame", "neutral_image", "neutral_clip"))
    if not rest_given and clip.neutral is not None:
        kind = "neutral_image" if Path(clip.neutral).suffix.lower() in IMAGE_EXTENSIONS else "neutral_clip"
        changes[kind] = clip.neutral
    return dataclasses.replace(options, track=dataclasses.replace(track, **changes)) if changes else options


def _run_clip(path: str, out: str, name: str, options: Any) -> dict:
    """Worker body: one clip through the pipeline; never raises for a bad clip."""
    t0 = time.perf_counter()
    try:
        report = run(path, out, options, progress=False, name=name)
        return {"status": "ok", "seconds": round(time.perf_counter() - t0, 3), "error": None,
                "frames": report["frames"], "output_dir": report["output_dir"]}
    except CaptureError as exc:
        error = str(exc)
    except Exception as exc:  # a bug on one clip must not end the batch
        error = f"{exc.__class__.__name__}: {exc}"
    return {"status": "failed", "seconds": round(time.perf_counter() - t0, 3), "error": error}


class _Report:
    """``batch_report.json``, rewritten after every finished clip."""

    def __init__(self, out: Path, clips: list[BatchClip], options: Any):
        self.path = out / REPORT_NAME
        self.t0 = time.perf_counter()
        self.entries = [{"path": c.path, "name": c.name, "status": "pending", "seconds": None, "error": None,
                         **({"neutral": c.neutral} if c.neutral else {}), **({"rom": c.rom} if c.rom else {})}
                        for c in clips]
        # An earlier batch's entries stay; this batch's replace those of the same clip.
        merged = [dict(e, earlier=True) for e in _earlier_entries(self.path)]
        where = {e.get("name"): k for k, e in enumerate(merged)}
        for e in self.entries:
            if e["name"] in where:
                merged[where[e["name"]]] = e
            else:
                merged.append(e)
        self.data = {"output": str(out), "options": _options_dict(options), "clips": merged}

    def set(self, i: int, result: dict) -> None:
        self.entries[i].update(result)
        self.write()

    def write(self) -> None:
        self.data["summary"] = {  # this batch's clips
            s: sum(1 for c in self.entries if c["status"] == s) for s in ("ok", "failed", "skipped", "pending")
        }
        self.data["earlier"] = len(self.data["clips"]) - len(self.entries)  # entries kept from before
        self.data["seconds"] = round(time.perf_counter() - self.t0, 3)
        write_text_atomic(self.path, json.dumps(self.data, indent=2) + "\n")


def _earlier_entries(path: Path) -> list[dict]:
    """The clip entries of an existing batch_report.json ([] when there is none or it is
    unreadable)."""
    try:
        clips = json.loads(path.read_text(encoding="utf-8")).get("clips")
    except (OSError, ValueError, AttributeError):
        return []
    return [c for c in clips if isinstance(c, dict) and isinstance(c.get("name"), str)] \
        if isinstance(clips, list) else []


#: RunOptions that change no output (left out of the resume comparison).
_RESUME_IGNORED = {"queue_frames", "track_workers"}


def _option_key(name: str, value: Any) -> Any:
    """An option value as compared by resume: characters and files by resolved path (the
    default avatar also as None), numbers as numbers."""
    if name == "character" and value in (None, "default"):
        return "default"
    if name in ("character", "face_model", "neutral_image", "neutral_clip", "calibration") and isinstance(value, str) \
            and Path(value).exists():
        return str(Path(value).resolve())
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


def resume_check(folder: str | os.PathLike, options: Any, clip: str | os.PathLike | None = None
                 ) -> tuple[bool, str | None]:
    """Whether ``folder`` holds a complete run of ``clip`` made with ``options`` (skip it),
    and if not, why it is run again (None when there is no earlier run there).

    The options stored in its report.json are compared with the requested ones, both
    normalised as report.json writes them; an option missing from an older report counts
    as its default. With ``clip``, its input files (the clip, a character file and its
    mapping JSON) are compared with the fingerprints report.json stores (size,
    modification time, a hash of the first and last MiB): a file replaced at the same
    path is run again.
    """
    folder = Path(folder)
    if not (folder / "report.json").exists():
        return False, None
    if not outputs_complete(folder):
        return False, "outputs incomplete"
    try:
        stored = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        stored = None
    if not isinstance(stored, dict) or not isinstance(stored.get("options"), dict):
        return False, "no options in its report.json"
    changed = _changed_options(stored["options"], options)
    if changed:
        return False, "options changed: " + ", ".join(changed)
    if clip is not None:
        if not isinstance(stored.get("inputs"), dict):
            return False, "no input fingerprints in its report.json (made by an older version)"
        changed = [f"{role.split(':', 1)[0]} {path} changed ({', '.join(diff)})"  # "character file:a.bin" -> its path
                   for role, path in input_files(clip, options).items()
                   if (diff := changes(stored["inputs"].get(role), fingerprint(path)))]
        if changed:
            return False, "; ".join(changed)
    return True, None


def _changed_options(stored: dict, options: Any) -> list[str]:
    """``"name old -> new"`` for each option (but :data:`_RESUME_IGNORED`) that differs."""
    wanted = options_json(options)
    defaults = options_json(RunOptions())
    # A stage's settings off their defaults are stored only when there are some.
    extra = ("track", "render", "retarget", "calibration")
    names = list(wanted) + [n for n in extra if n in stored and n not in wanted]
    changed = []
    for name in names:
        new = wanted.get(name)
        if name in _RESUME_IGNORED:
            continue
        old = stored.get(name, defaults.get(name))
        if _option_key(name, old) != _option_key(name, new):
            changed.append(f"{name} {old} -> {new}")
    return changed


def _failure_line(path: str, error: str | None) -> str:
    """``failed: <path>: <error>``, the path once (most errors start with it)."""
    error = error or "failed"
    if path in error or os.path.basename(path) in error:
        return f"failed: {error}"
    return f"failed: {path}: {error}"


def _options_dict(options: Any) -> dict:
    """batch_report.json's options: report.json's, but a FaceRig character left out."""
    if not isinstance(options, RunOptions):
        return {}
    jsonable = options.character is None or isinstance(options.character, (str, os.PathLike))
    return {k: v for k, v in options_json(options).items() if k != "character" or jsonable}


def run_batch(inputs: Iterable[str | os.PathLike], out: str | os.PathLike, options: Any = None,
              jobs: int | None = None, resume: bool = False, ray_address: str | None = None,
              progress: bool = True) -> dict:
    """Run :func:`capture2face.pipeline.run` on many clips.

    Args:
        inputs: clips, folders, glob patterns or list files (see :func:`expand_inputs`).
        out: output folder; clip ``x.mp4`` goes to ``out/x/``.
        options: a :class:`~capture2face.pipeline.RunOptions` shared by every clip.
        jobs: clips processed at once (default: the cores this process may use, at most the
            clip count).
            ``jobs=1`` runs the clips one after another in this process.
        resume: skip clips whose ``out/<name>/`` holds a complete run made with the same
            options (:func:`resume_check`); the others run (again).
        ray_address: distribute the clips as Ray tasks ("local", "auto", "ray://...").
        progress: a progress bar over clips.
    Returns:
        The report written to ``out/batch_report.json``: ``clips`` (path, name, status
        ok/failed/skipped, seconds, error, ``rerun``: why a resumed clip ran again; entries
        of an earlier batch into ``out`` for other clips kept with ``"earlier": true``),
        ``summary`` (this batch's counts), ``earlier`` (entries kept), ``seconds``.
    Raises:
        CaptureError: no clips found, output folder not writable, Ray not installed.
    """
    options = options or RunOptions()
    out = Path(out)
    if jobs is not None and int(jobs) < 1:
        raise CaptureError(f"--jobs {jobs}: must be 1 or more (the clips run at once)")
    clips = expand_inputs(inputs)
    check_writable(out)
    _check_batch(options, progress, ray_address)
    # Joined before anything is written: a dead address fails in one line, in seconds.
    ray, started = _connect_ray(ray_address) if ray_address else (None, False)
    try:
        return _batch(clips, out, options, jobs, resume, ray_address, progress)
    finally:
        if started:
            ray.shutdown()


def _batch(clips: list[BatchClip], out: Path, options: Any, jobs: int | None, resume: bool,
           ray_address: str | None, progress: bool) -> dict:
    """:func:`run_batch` once the checks passed: plan, run, report."""
    report = _Report(out, clips, options)
    todo = _plan_clips(report, clips, out, options, resume)
    bar = None
    if progress:
        bar = tqdm(total=len(clips), initial=len(clips) - len(todo), desc="clips", unit="clip")
    try:
        options, failed = _learn_takes(clips, todo, options, progress)
        done = _clip_done(report, clips, bar)
        for i, error in failed.items():
            done(i, {"status": "failed", "seconds": 0.0, "error": error})
        todo = [i for i in todo if i not in failed]
        if todo:
            _run_clips(clips, todo, out, options, jobs, ray_address, done)
    finally:
        if bar is not None:
            bar.close()
        report.write()
    return report.data


def _check_batch(options: Any, progress: bool, ray_address: str | None) -> None:
    """The checks :func:`run_batch` makes before any clip runs (raise CaptureError)."""
    # Checked once for the whole batch, before any clip is tracked: the options and their
    # limits, the face model, a drivable character (the default avatar is), and the GL
    # context where the workers are local processes (a Ray worker may be another machine).
    # The default avatar too: built here once (then cached) rather than by every worker.
    options.validate()
    check_calibration(options.track)  # an actor.json loads, a take decodes: before a first avatar build
    check_shared(options, progress)
    if not ray_address:
        check_gl()


def _learn_takes(clips: list[BatchClip], todo: list[int], options: Any, progress: bool
                 ) -> tuple[Any, dict[int, str]]:
    """Learn each range-of-motion take the clips ``todo`` use once, here, before any clip
    runs (not once per clip): the batch's ``--calibration`` take (``options`` come back
    carrying what it learned) and each ``CLIP.rom.<video>`` (into its clips' ``learned``).
    A take that cannot be learned fails the clips that use it: ``{index: error}``."""
    if not todo:
        return options, {}
    track = options.track
    shared = track.calibration
    if isinstance(shared, (str, os.PathLike)) and not is_calibration_file(shared):
        try:
            learned = learn_calibration(shared, track, progress)
        except CaptureError as exc:
            return options, dict.fromkeys(todo, str(exc))
        return dataclasses.replace(options, track=dataclasses.replace(track, calibration=learned)), {}
    takes: dict[str, Any] = {}  # a take's resolved path -> its ActorCalibration, or the error learning it
    failed = {}
    for i in todo:
        rom = clip_options(clips[i], options).track.calibration
        if not isinstance(rom, str) or is_calibration_file(rom) or rom != clips[i].rom:
            continue  # the batch's own calibration, an actor.json (loaded by the clip), or none
        key = str(Path(rom).resolve())
        if key not in takes:
            try:
                takes[key] = learn_calibration(rom, track, progress)
            except CaptureError as exc:
                takes[key] = str(exc)
        if isinstance(takes[key], str):
            failed[i] = takes[key]
        else:
            clips[i].learned = takes[key]
    return options, failed


def _plan_clips(report: _Report, clips: list[BatchClip], out: Path, options: Any, resume: bool) -> list[int]:
    """The indices of the clips to run; with ``resume`` the complete ones are marked skipped
    and the others say why they run again. Writes the report."""
    todo = []
    for i, c in enumerate(clips):
        skip, why = resume_check(out / c.name, clip_options(c, options), c.path) if resume else (False, None)
        if skip:
            report.entries[i].update(status="skipped", seconds=0.0, error=None)
        else:
            if why:
                report.entries[i]["rerun"] = why
            todo.append(i)
    report.write()
    return todo


def _clip_done(report: _Report, clips: list[BatchClip], bar):
    """The callback ``done(i, result)`` a finished clip ``i`` reports to: its report entry,
    the progress bar and, for a failure, a line on stderr (under the bar)."""

    def done(i: int, result: dict) -> None:
        report.set(i, result)
        if result["status"] == "failed":  # on stderr, with or without the bar
            line = _failure_line(clips[i].path, result["error"])
            if bar is not None:
                bar.write(line, file=sys.stderr)
            else:
                print(line, file=sys.stderr)
        if bar is not None:
            bar.update(1)

    return done


def _run_clips(clips: list[BatchClip], todo: list[int], out: Path, options: Any, jobs: int | None,
               ray_address: str | None, done) -> None:
    """Run the clips ``todo``: as Ray tasks, one after another in this process (one job),
    or in a process pool."""
    n_jobs = max(1, min(jobs or free_cores(), len(todo)))
    if (ray_address or n_jobs > 1) and options.track.workers is None:
        # Clips in parallel already fill the cores (and a Ray task has one CPU):
        # each tracks with one landmarker (segment workers on top would
        # oversubscribe them).
        options = dataclasses.replace(options, track=dataclasses.replace(options.track, workers=1))
    if ray_address:
        _run_ray(clips, todo, out, options, ray_address, done)
    elif n_jobs == 1:
        for i in todo:
            done(i, _run_clip(clips[i].path, str(out), clips[i].name, clip_options(clips[i], options)))
    else:
        _run_pool(clips, todo, out, options, n_jobs, done)


def _run_pool(clips: list[BatchClip], todo: list[int], out: Path, options: Any, n_jobs: int,
              done) -> None:
    """The clips ``todo``, ``n_jobs`` at a time, each in a fresh process of its own,
    started only when a slot is free: an interrupt leaves no clip queued to start after
    it. A clip whose process dies (segfault, out of memory) is run once more."""
    ctx = multiprocessing.get_context("spawn")  # fork would copy threads and GL state
    queue, running = list(todo), []
    attempts = dict.fromkeys(todo, 0)
    try:
        while queue or running:
            while queue and len(running) < n_jobs:
                worker = _clip_worker(ctx, clips, queue.pop(0), out, options)
                running.append(worker)  # before it starts: an interrupt stops it too
                attempts[worker.i] += 1
                worker.start()
            ready = set(multiprocessing.connection.wait([w.conn for w in running]))
            for worker in [w for w in running if w.conn in ready]:
                result = worker.result()
                running.remove(worker)
                if result is None and attempts[worker.i] < _MAX_ATTEMPTS:
                    queue.insert(0, worker.i)
                    continue
                done(worker.i, result or {"status": "failed", "seconds": None,
                                          "error": "the worker process crashed on this clip"})
    except BaseException:
        # Interrupted: the running clips unwind (SIGTERM raises KeyboardInterrupt there,
        # so their staged outputs are removed) before this process exits.
        for worker in running:
            worker.terminate()
        for worker in running:
            worker.join()
            worker.conn.close()
        raise


@dataclasses.dataclass
class _Worker:
    """A clip's process and the ends of the pipe its result comes through."""

    i: int
    process: Any
    conn: Any  # this process's end
    send: Any  # the child's end, closed here once it started

    def start(self) -> None:
        """Start the process. It inherits SIGINT ignored, until its handler is in place (a
        Ctrl-C while it imports would print a traceback there; this process stops it with
        SIGTERM). Meanwhile, the ~20 ms of the start, this process ignores SIGINT too and
        holds SIGTERM, raised once the child is started (and so known to the caller, who
        stops it)."""
        if threading.current_thread() is not threading.main_thread():
            self._start()
            return
        held: list[int] = []

        def hold(signum, frame):
            held.append(signum)

        handlers = {signal.SIGINT: signal.signal(signal.SIGINT, signal.SIG_IGN),
                    signal.SIGTERM: signal.signal(signal.SIGTERM, hold)}
        try:
            self._start()
        finally:
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
        if held:
            raise KeyboardInterrupt

    def _start(self) -> None:
        try:
            self.process.start()
        finally:
            self.send.close()  # the pipe ends (EOF) when the child does

    def result(self) -> dict | None:
        """The clip's result (None: the process died without one); waits for the process."""
        try:
            result = self.conn.recv()
        except (EOFError, OSError):
            result = None
        self.conn.close()
        self.join()
        if isinstance(result, dict) and result.get("status") == "interrupted":
            raise KeyboardInterrupt  # the worker alone was stopped (SIGTERM, SIGINT): so is the batch
        return result

    def terminate(self) -> None:
        if self.process.pid is not None and self.process.is_alive():
            self.process.terminate()

    def join(self) -> None:
        """Wait for the process to end: :data:`_STOP_S` seconds, then it is killed."""
        if self.process.pid is None:
            return
        self.process.join(_STOP_S)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()


def _clip_worker(ctx, clips: list[BatchClip], i: int, out: Path, options: Any) -> _Worker:
    """Clip ``i``'s process, not started."""
    receive, send = ctx.Pipe(duplex=False)
    process = ctx.Process(target=_clip_process, name=f"capture2face-clip-{i}",
                          args=(send, clips[i].path, str(out), clips[i].name, clip_options(clips[i], options)))
    return _Worker(i, process, receive, send)


def _clip_process(conn, path: str, out: str, name: str, options: Any) -> None:
    """A clip's process: runs it and sends its result ({"status": "interrupted"} after
    SIGINT or SIGTERM, which unwind like Ctrl-C: outputs are staged, so nothing is left
    half-written)."""
    install_process_defaults()  # SIGINT too, ignored until here (see _Worker.start)
    warnings_to_stderr()  # the clip's warnings with the usual prefix
    try:
        result = _run_clip(path, out, name, options)
    except KeyboardInterrupt:
        result = {"status": "interrupted"}
    with contextlib.suppress(OSError, KeyboardInterrupt):
        conn.send(result)
    # Done: its outputs are in place (or removed). Ended here, after the exit handlers:
    # Python's own exit waits for every thread, and one an interrupt left behind (started
    # but not yet known to its pool) would keep the process, and the batch, waiting.
    with contextlib.suppress(BaseException):
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
    os._exit(0)


def _ray_endpoint(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a ``HOST:PORT`` or ``ray://HOST[:PORT]`` address (None for
    "auto" and "local", which name no endpoint)."""
    if address in ("auto", "local"):
        return None
    client = address.startswith("ray://")
    rest = address[len("ray://"):] if client else address
    host, sep, port = rest.rpartition(":")
    if not sep or not host:
        host, port = rest, "10001" if client else "6379"
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise CaptureError(f"--ray {address}: not an address (HOST:PORT, ray://HOST:PORT, auto or local)") from None


def _probe(address: str, deadline: float) -> None:
    """Refuse an address where nothing listens, or that does not answer, in one line
    (Ray itself retries a dead address for minutes)."""
    endpoint = _ray_endpoint(address)
    if endpoint is None:
        return
    try:
        socket.create_connection(endpoint, timeout=max(1.0, deadline - time.monotonic() - 3.0)).close()
    except TimeoutError:
        raise CaptureError(f"--ray {address}: no answer from {endpoint[0]}:{endpoint[1]} "
                           f"within {RAY_CONNECT_S - 3:.0f} s; is the address right and the cluster up?") from None
    except OSError as exc:
        raise CaptureError(f"--ray {address}: cannot connect to {endpoint[0]}:{endpoint[1]} "
                           f"({exc.strerror or exc}); is a Ray cluster running there (ray start --head)?") from None


@contextlib.contextmanager
def _stderr_muted():
    """File descriptor 2 to /dev/null inside the block (C++ libraries write there directly).
    Yields a dict: with ``keep`` set, fd 2 stays muted after the block (a thread that is
    still writing there) and ``sys.stderr`` moves to the terminal's own descriptor."""
    sys.stderr.flush()
    saved = os.dup(2)
    state = {"keep": False}
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), 2)
    try:
        yield state
    finally:
        if state["keep"]:
            sys.stderr = open(saved, "w", encoding="utf-8", errors=PATH_ERRORS, buffering=1)  # noqa: SIM115
        else:
            os.dup2(saved, 2)
            os.close(saved)


def _connect_ray(address: str):
    """``(ray, started)``: Ray connected to ``address`` ("local" starts an instance), or a
    CaptureError naming the address within :data:`RAY_CONNECT_S` seconds."""
    try:
        import ray
    except ImportError:
        raise CaptureError("--ray needs Ray: pip install 'capture2face[ray]'") from None
    if ray.is_initialized():
        return ray, False
    if address == "local":  # nothing to reach; Ray starts its processes from this (the main) thread
        ray.init(include_dashboard=False, log_to_driver=False)
        return ray, True
    deadline = time.monotonic() + RAY_CONNECT_S
    _probe(address, deadline)
    result: dict[str, BaseException | None] = {}

    # In a thread: a deadline, and Ray leaves our SIGTERM handler alone. (Only to join a
    # cluster: processes Ray starts from a thread die with it, PR_SET_PDEATHSIG.)
    def connect() -> None:
        try:
            ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
            result["error"] = None
        except BaseException as exc:  # handed to the main thread
            result["error"] = exc

    thread = threading.Thread(target=connect, name="capture2face-ray-connect", daemon=True)
    with _stderr_muted() as muted:  # Ray's C++ client warns every second while it retries
        thread.start()
        thread.join(max(0.0, deadline - time.monotonic()))
        muted["keep"] = thread.is_alive()  # given up on: it goes on retrying (and warning) until exit
    if "error" not in result:
        raise CaptureError(f"--ray {address}: no Ray cluster answered within {RAY_CONNECT_S:.0f} s")
    if isinstance(result["error"], ConnectionError) and address == "auto":
        raise CaptureError("--ray auto: no running Ray cluster found on this machine; start one "
                           "(ray start --head), or use --ray HOST:PORT or --ray local") from None
    if isinstance(result["error"], Exception):
        raise CaptureError(f"--ray {address}: cannot join the cluster ({result['error']})") from None
    if result["error"] is not None:
        raise result["error"]
    return ray, True


def _run_ray(clips: list[BatchClip], todo: list[int], out: Path, options: Any, address: str,
             done) -> None:
    """The clips as Ray tasks (Ray joined by :func:`run_batch`)."""
    import ray

    # Each task is a clip; MediaPipe and the renderer use the worker's own cores.
    task = ray.remote(num_cpus=1, max_retries=1)(_run_clip)
    refs = {task.remote(clips[i].path, str(out.resolve()), clips[i].name, clip_options(clips[i], options)): i
            for i in todo}
    remaining = list(refs)
    while remaining:
        ready, remaining = ray.wait(remaining, num_returns=1)
        for ref in ready:
            i = refs[ref]
            try:
                done(i, ray.get(ref))
            except Exception as exc:  # the worker died (RayTaskError, ...)
                done(i, {"status": "failed", "seconds": None,
                         "error": f"ray task failed: {exc.__class__.__name__}"})

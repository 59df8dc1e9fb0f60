"""Any character, loaded: the built-in avatars, a FaceRig .npz, or a user's .glb / .gltf
(with its mapping JSON and its automatic wrinkles)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from capture2face.character.auto_wrinkles import automatic_wrinkles
from capture2face.character.landmark_sources import NONE, with_landmarks
from capture2face.character.lending import lend_from_avatar
from capture2face.character.prepared import load_prepared, preparation_key, prepared_dir, store_prepared
from capture2face.errors import CaptureError
from capture2face.gltf.container import CHARACTER_SUFFIXES
from capture2face.gltf.rig_import import read_glb
from capture2face.measures import landmark_faults
from capture2face.rig import avatar
from capture2face.rig.arkit_names import drive_mode, is_automatic
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.log import collect_warnings, log

BUILTIN_CHARACTERS = ("default", "wide")


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
        if suffix in CHARACTER_SUFFIXES:
            return _imported_character(path)
    except CaptureError as exc:
        # The readers turn a malformed file into CaptureError; anything else is a bug of
        # ours and keeps its traceback (--debug) instead of blaming the user's file.
        msg = str(exc)
        raise CaptureError(msg if msg.startswith(("character", str(path))) else f"character {path}: {msg}") from None
    raise CaptureError(f"character {path}: unsupported format '{suffix}'; "
                       "use a FaceRig .npz, a .glb (with its mapping .json) or a .vrm")


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
    automatic wrinkles; the same rig again while neither file changes (in this process),
    and from the disk cache while no file's content changes (:mod:`.prepared`)."""
    mapping = path.with_suffix(".json")
    key = (_file_key(path), _file_key(mapping))
    if key in _IMPORTED:
        rig, said = _IMPORTED[key]
        for message in said:  # what the import warned, said again for this use
            log.warning("%s", message)
        return rig

    t = time.perf_counter()
    content_key = preparation_key(path, mapping if mapping.is_file() else None)
    cached = load_prepared(content_key)
    if cached is not None:
        rig, said = cached
        for message in said:
            log.warning("%s", message)
        log.info("character %s: prepared copy read from %s in %.2f s", path.name, prepared_dir(),
                 time.perf_counter() - t)
    else:
        with collect_warnings(reported=False) as said:
            rig = with_automatic_wrinkles(import_glb(path, mapping if mapping.is_file() else None))
        said = list(said)
        store_prepared(content_key, rig, said)
        log.info("character %s: prepared in %.1f s (import, landmarks, baked maps; cached in %s)", path.name,
                 time.perf_counter() - t, prepared_dir())
    _IMPORTED.clear()  # one character kept: a body .glb may be hundreds of MB
    _IMPORTED[key] = rig, said
    return rig


def import_glb(path: str | os.PathLike, mapping_json: str | os.PathLike | None = None) -> FaceRig:
    """A user's character .glb / .gltf (and its mapping JSON: ``mapping_json``, else the
    file's path with ``.json`` where it exists) as a FaceRig: what the files give
    (:func:`capture2face.gltf.rig_import.import_glb`) plus what the default avatar lends a
    character with bones tied to landmarks (:mod:`.lending`). Our own exports come back
    as they were written."""
    imported = read_glb(path, mapping_json)
    return imported.rig if imported.own_export else lend_from_avatar(imported.rig, imported.mapping)


def with_automatic_wrinkles(rig: FaceRig) -> FaceRig:
    """A morph character without face bones with its landmarks
    (:func:`~capture2face.character.landmark_sources.with_landmarks`: its front view
    tracked, else from its morphs) and then its automatic wrinkle influences
    (:mod:`capture2face.character.auto_wrinkles`) where its morphs allow; any other rig as it
    is. Each step that fails says so in one warning and leaves what the others found (a
    head whose wrinkles cannot be baked keeps its landmarks)."""
    try:
        if is_automatic(rig) or drive_mode(rig) != "arkit":
            return rig
    except CaptureError:
        return rig  # undrivable: the check before tracking says why
    rig = with_landmarks(rig)
    if rig.landmark_source == NONE:
        return rig
    try:
        rig = automatic_wrinkles(rig)
    except CaptureError as exc:
        log.warning("no automatic wrinkles: %s", exc)
    warn_landmark_faults(rig)
    return rig


def warn_landmark_faults(rig: FaceRig) -> dict[str, str]:
    """The load-time check of automatically cast landmarks
    (:func:`capture2face.measures.landmark_faults`): one warning naming the landmark pairs
    that do not move with their morphs (the character still runs; the fidelity figures leave
    those measures out). Returns the faults."""
    faults = landmark_faults(rig)
    if faults:
        log.warning("character '%s': its automatic landmarks do not follow its morphs (%s); fidelity leaves out %s",
                    rig.name, "; ".join(faults.values()), ", ".join(faults))
    return faults


def builtin_avatar(variant: str | None = None, progress: bool = False) -> FaceRig:
    """:func:`~capture2face.rig.avatar.default_avatar`, with a progress bar (and an entry
    in the log) when it is not cached yet: its build takes ~5 s, once per machine and
    version (``run`` counts it in report.json's ``seconds["checks"]``)."""
    if avatar.is_cached(variant):
        return avatar.default_avatar(variant)

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

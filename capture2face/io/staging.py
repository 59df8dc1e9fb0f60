"""All-or-nothing output folders that hold a user's own files too.

A run writes its files into a hidden staging folder beside its output folder
(``OUT/.tmp-<name>-*``) and moves them into ``OUT/<name>/`` only when every one of them is
complete. It never replaces the output folder as a whole: the files the run writes, and
the files an earlier run wrote there, are the only ones it replaces or removes; anything
else in the folder (notes, the source clip itself) is left untouched.

Which files a run owns (the *manifest*): the ``outputs`` listed in the folder's
``report.json`` plus ``report.json`` itself (only names the caller declares as its
outputs, so a hand-edited report cannot make a run delete a user's file). A name the run
wants to write that exists in the folder but is owned by no run is a conflict (a
:class:`CaptureError`, before any slow work): such a file is never overwritten. A path in
``protect`` (the source clip) is never replaced nor removed, whatever its name.

Moving in (the commit), in this order:

1. ``.capture2face-run.json`` (the journal) is written atomically into the folder; it lists
   the old run's files and the new run's;
2. the old ``report.json`` is removed, so the folder no longer reads as a complete run
   (:func:`capture2face.pipeline.outputs_complete`, ``batch --resume``);
3. each new file is renamed in (``os.replace``, atomic per file), ``report.json`` last;
4. the old run's files the new run did not write (e.g. compare.mp4 when the new run has
   compare off) are removed;
5. the journal is removed.

A crash (power loss, SIGKILL) between two of these steps can leave the folder without
``report.json`` holding a mix of old and new run files plus the journal, never a
half-written file and never a change to a user's file; the folder then reads as
incomplete, and the next run into it, which takes the journal's files as its own,
replaces them. An exception (a full disk, SIGINT, SIGTERM) before step 2 leaves the
folder as it was; one from a failing rename in step 3 leaves the state a crash would.

One run at a time per output folder: a run holds ``OUT/.capture2face-<name>.lock``
(``flock``, released however the process ends; the file is removed with the lock) from
before its staging folder is made until its files are moved in; a second run into the
same folder is refused at once in one line, rather than one of them losing its work.

Staging folders record their owner (``.owner``: pid, host, start time). A run removes the
staging folders that a killed run left in ``OUT`` (owner process gone, started before this
run; or, from versions that wrote no owner, untouched for :data:`UNOWNED_STALE_S`) and
warns about it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Collection, Iterable, Iterator
from pathlib import Path

from capture2face.errors import CaptureError
from capture2face.io.atomic import DIR_MODE, FILE_MODE, write_text_atomic

STAGING_PREFIX = ".tmp-"
LOCK_PREFIX = ".capture2face-"
OWNER_FILE = ".owner"
JOURNAL = ".capture2face-run.json"
MANIFEST = "report.json"
_NO_ROOM = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}
UNOWNED_STALE_S = 3600.0  # a staging folder without .owner, untouched this long, is stale

log = logging.getLogger("capture2face")


def _make_parents(folder: Path) -> list[Path]:
    """``mkdir -p folder``; returns the folders it created, deepest last.

    Raises:
        CaptureError: the folder cannot be created (read-only, a file in the way, ...).
    """
    missing: list[Path] = []
    p = folder
    while not p.exists():
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    if p.exists() and not p.is_dir():
        raise CaptureError(f"cannot write to output folder {folder}: {p} is a file, not a folder")
    missing.reverse()
    for i, d in enumerate(missing):
        try:
            d.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            _remove_empty(missing[:i])
            raise CaptureError(f"cannot write to output folder {folder}: {exc.strerror or exc}") from None
    return missing


def _remove_empty(created: list[Path]) -> None:
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            break  # not empty (someone else wrote there) or already gone


# ---- ownership ----------------------------------------------------------------------------
def _read_json(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def owned_files(folder: str | os.PathLike, known: Collection[str]) -> set[str]:
    """Names of the files in ``folder`` that an earlier run wrote (see module doc): the
    manifest's (report.json's ``outputs`` and report.json) and an interrupted commit's
    journal's, restricted to ``known`` names."""
    folder = Path(folder)
    owned: set[str] = set()
    report = _read_json(folder / MANIFEST)
    if isinstance(report, dict) and isinstance(report.get("outputs"), list):
        owned.add(MANIFEST)
        owned.update(n for n in report["outputs"] if isinstance(n, str))
    journal = _read_json(folder / JOURNAL)
    if isinstance(journal, dict) and isinstance(journal.get("files"), list):
        owned.update(n for n in journal["files"] if isinstance(n, str))
    return {n for n in owned if n in known and "/" not in n and n not in (".", "..")}


def _same_file(path: Path, others: Iterable[Path]) -> bool:
    for other in others:
        try:
            if os.path.samefile(path, other):
                return True
        except OSError:
            continue
    return False


# The longest file name most file systems take (ext4, APFS, NTFS: 255 bytes).
NAME_MAX = 255


def folder_name_problem(name: str) -> str | None:
    """Why ``name`` cannot name an output folder (``OUT/<name>``), or None.

    Beside the folder in ``OUT`` a run keeps its lock (``.capture2face-<name>.lock``) and
    staging folders (``.tmp-<name>-*``, which a later run removes as a killed run's): a
    folder named like them would be taken for them.
    """
    if not name.strip():
        return "is empty"
    if name in (".", ".."):
        return f"'{name}' is not a folder name"
    if "/" in name or (os.altsep and os.altsep in name):
        return "contains a path separator; give a plain folder name (the folder it goes in is -o)"
    if "\0" in name:
        return "contains a NUL character"
    if any(ord(c) < 32 or ord(c) == 127 for c in name):  # a newline or tab splits the folder's name in lists
        return "contains a control character (a newline, tab or escape); give a plain folder name"
    for prefix in (STAGING_PREFIX, LOCK_PREFIX):
        if name.startswith(prefix):
            return f"starts with '{prefix}', the name of capture2face's own hidden files beside the outputs"
    longest = len(os.fsencode(lock_path(name).name))
    if longest > NAME_MAX:
        return f"is too long ({len(os.fsencode(name))} bytes; at most {len(os.fsencode(name)) - longest + NAME_MAX})"
    return None


def _manifest_problem(final: Path) -> str | None:
    """Why ``final``'s existing report.json cannot tell which files an earlier run wrote
    (unreadable, not JSON, not a run's report), or None (none there, or a run's)."""
    path = final / MANIFEST
    if not os.path.lexists(path):
        return None
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    except UnicodeDecodeError:
        return "cannot be read (not UTF-8 text)"
    except ValueError as exc:
        return f"cannot be read (not valid JSON: {exc})"
    if not (isinstance(report, dict) and isinstance(report.get("outputs"), list)):
        return "is not a capture2face run's report (it lists no \"outputs\")"
    return None


def _folder_not_writable(final: Path) -> str | None:
    """Why the existing folder ``final`` cannot take files, or None."""
    if os.access(final, os.W_OK | os.X_OK):
        return None
    with contextlib.suppress(OSError):
        if os.statvfs(final).f_flag & os.ST_RDONLY:
            return "it is on a read-only file system"
    return "it is read-only (no permission to write there)"


def check_output_folder(final: str | os.PathLike, names: Iterable[str], known: Collection[str],
                        protect: Iterable[str | os.PathLike] = ()) -> set[str]:
    """Fail early when a run could not move ``names`` into ``final`` without touching a
    file it does not own; returns the names an earlier run owns there.

    Raises:
        CaptureError: ``final`` is a file or a folder this process cannot write; its
            report.json cannot tell the earlier run's files; a name to write is a protected
            file (the source clip), a folder, or a file no run owns.
    """
    final = Path(final)
    if final.exists() and not final.is_dir():
        raise CaptureError(f"cannot write outputs to {final}: it is a file, not a folder")
    if not final.is_dir():
        return set()
    names = list(names)
    why = _folder_not_writable(final)
    if why:
        raise CaptureError(f"cannot write to output folder {final}: {why}; make it writable or choose "
                           "another output folder")
    why = _manifest_problem(final) if MANIFEST in names else None
    if why:
        raise CaptureError(f"{final / MANIFEST}: {why}, so which files there an earlier run wrote is unknown; "
                           f"move {final} aside or choose another output folder")
    protect = [Path(p) for p in protect]
    owned = owned_files(final, known)
    for name in names:
        target = final / name
        if not os.path.lexists(target):
            continue
        if _same_file(target, protect):
            raise CaptureError(f"{target}: the source clip would be overwritten by the output of the same name; "
                               "move the clip or choose another output folder")
        if target.is_dir() and not target.is_symlink():
            raise CaptureError(f"{target}: a folder is in the way of an output file; move it or choose another "
                               "output folder")
        if name not in owned:
            raise CaptureError(f"{target}: exists and no earlier run wrote it (it is not in {final / MANIFEST}); "
                               "move it or choose another output folder")
    return owned


# ---- stale staging folders ----------------------------------------------------------------
def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # someone else's process (or a nonsense pid: leave the folder alone)
    return True


def _newest_mtime(folder: Path) -> float:
    newest = folder.lstat().st_mtime
    for root, dirs, files in os.walk(folder):
        for n in dirs + files:
            with contextlib.suppress(OSError):
                newest = max(newest, os.lstat(os.path.join(root, n)).st_mtime)
    return newest


def _tree_bytes(folder: Path) -> int:
    total = 0
    for root, _, files in os.walk(folder):
        for n in files:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(root, n)).st_size
    return total


def _is_stale(folder: Path, now: float) -> bool:
    owner = _read_json(folder / OWNER_FILE)
    if isinstance(owner, dict):
        try:
            pid, host, started = int(owner["pid"]), str(owner["host"]), float(owner["started"])
        except (KeyError, TypeError, ValueError):
            return False
        if host != socket.gethostname() or started >= now:
            return False  # another machine's run (shared disk), or not older than this run
        return not _pid_alive(pid)
    try:
        return now - _newest_mtime(folder) > UNOWNED_STALE_S
    except OSError:
        return False


def clean_stale_staging(parent: str | os.PathLike, now: float | None = None) -> list[Path]:
    """Remove the staging folders in ``parent`` that no live run holds (a killed run's),
    with a warning naming them; returns them."""
    parent = Path(parent)
    now = time.time() if now is None else now
    removed: list[tuple[Path, int]] = []
    try:
        entries = list(parent.glob(f"{STAGING_PREFIX}*"))
    except OSError:
        return []
    for p in sorted(entries):
        try:
            if p.is_symlink() or not p.is_dir() or not _is_stale(p, now):
                continue
            size = _tree_bytes(p)
            shutil.rmtree(p)
        except OSError:
            continue  # gone meanwhile, or not ours to remove: leave it
        removed.append((p, size))
    if removed:
        listed = ", ".join(f"{p.name} ({size / 1e6:.1f} MB)" for p, size in removed)
        log.warning("removed %d staging folder(s) left in %s by runs that were killed: %s",
                    len(removed), parent, listed)
    return [p for p, _ in removed]


# ---- the staged run -----------------------------------------------------------------------
def _commit(tmp: Path, final: Path, known: Collection[str], protect: list[Path]) -> None:
    """Move the files of ``tmp`` into ``final`` (see the module doc for the order)."""
    names = sorted((p.name for p in tmp.iterdir() if p.is_file() and p.name != OWNER_FILE),
                   key=lambda n: (n == MANIFEST, n))  # the manifest last
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"staged files not declared as outputs: {unknown}")
    created = _make_parents(final)
    try:
        owned = check_output_folder(final, names, known, protect)
        stale = sorted(n for n in owned - set(names)
                       if os.path.lexists(final / n) and not _same_file(final / n, protect))
        _start_commit(final, sorted(owned | set(names)), MANIFEST in owned)
    except BaseException:
        _remove_empty(created)
        raise
    for n in names:
        os.replace(tmp / n, final / n)
    for n in stale:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(final / n)
    with contextlib.suppress(FileNotFoundError):
        os.unlink(final / JOURNAL)


def _start_commit(final: Path, files: list[str], drop_manifest: bool) -> None:
    """Steps 1 and 2 of the commit (the journal, the old report.json gone); a folder that
    became unwritable since the checks is named, not the journal's temporary file."""
    try:
        write_text_atomic(final / JOURNAL, json.dumps({"files": files}) + "\n")
        if drop_manifest:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(final / MANIFEST)
    except OSError as exc:
        if exc.errno in _NO_ROOM:
            exc.filename, exc.filename2 = str(final), None
            raise
        raise CaptureError(f"cannot write to output folder {final}: {exc.strerror or exc}") from None


@contextlib.contextmanager
def staged_folder(final: str | os.PathLike, known: Collection[str],
                  protect: Iterable[str | os.PathLike] = ()) -> Iterator[Path]:
    """Yield an empty staging folder beside ``final``; on success its files move into
    ``final`` (see the module doc), replacing only what an earlier run wrote there.

    Args:
        final: the output folder (created if needed).
        known: every name a run may write (its outputs); the staged files must be among
            them (subfolders of the staging folder, such as scratch space, are dropped).
        protect: files never to replace or remove (the source clip).

    On any exception, KeyboardInterrupt included, the staging folder is deleted and so
    are the parent folders this call created. Stale staging folders of killed runs in
    ``final``'s parent are removed first (with a warning).

    Raises:
        CaptureError: ``final``'s parent cannot be created or written, ``final`` is a file,
            or an output would overwrite a file no run wrote (:func:`check_output_folder`).
    """
    final = Path(final)
    protect = [Path(p) for p in protect]
    if final.exists() and not final.is_dir():
        raise CaptureError(f"cannot write outputs to {final}: it is a file, not a folder")
    started = time.time()
    created = _make_parents(final.parent)
    tmp = lock = None
    ok = False
    try:
        lock = lock_output(final)  # a second run into the same folder is refused, not silently lost
        clean_stale_staging(final.parent, now=started)
        tmp = _make_staging(final, started)
        yield tmp
        _commit(tmp, final, known, protect)
        ok = True
    except BaseException as exc:
        if isinstance(exc, OSError) and exc.filename is None and exc.errno in _NO_ROOM:
            exc.filename = str(final)  # a write by fd (pwrite, an encoder): name the folder
        raise
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if lock is not None:
            unlock_output(lock)
        if not ok:
            _remove_empty(created)


def _make_staging(final: Path, started: float) -> Path:
    """A new staging folder for ``final`` in its parent, with its ``.owner``."""
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{final.name}-", dir=final.parent))
    except OSError as exc:
        raise CaptureError(f"cannot write to output folder {final.parent}: {exc.strerror or exc}") from None
    try:
        os.chmod(tmp, DIR_MODE)  # mkdtemp made it owner-only
        (tmp / OWNER_FILE).write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                                  "started": started}) + "\n", encoding="utf-8")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


# ---- one run per output folder ------------------------------------------------------------
def lock_path(final: str | os.PathLike) -> Path:
    """The lock file of the output folder ``final`` (beside it, in its parent)."""
    final = Path(final)
    return final.parent / f"{LOCK_PREFIX}{final.name}.lock"


def lock_output(final: str | os.PathLike) -> tuple[int, Path]:
    """Hold the output folder ``final`` for this run (an advisory ``flock`` on its lock
    file, released by :func:`unlock_output` or when the process ends, however it ends).

    Raises:
        CaptureError: another live run holds it (its pid, host and start time named).
    """
    path = lock_path(final)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, FILE_MODE)
        except OSError as exc:
            raise CaptureError(f"cannot write to output folder {path.parent}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _read_json(path)
            os.close(fd)
            raise CaptureError(f"{final}: another run is writing there{_holder(holder)}; wait for it to "
                               "finish, or choose another output folder") from None
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False  # its holder removed it between our open and our lock: take the new one
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.write(fd, (json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()})
                  + "\n").encode("utf-8"))
    return fd, path


def _holder(info) -> str:
    if not isinstance(info, dict):
        return ""
    try:
        when = time.strftime("%H:%M:%S", time.localtime(float(info["started"])))
        return f" (pid {int(info['pid'])} on {info['host']}, since {when})"
    except (KeyError, TypeError, ValueError):
        return ""


def unlock_output(lock: tuple[int, Path]) -> None:
    """Release :func:`lock_output`'s lock and remove its file (while still held, so that
    no other run is holding a lock on a file that is gone)."""
    fd, path = lock
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
    os.close(fd)


def check_writable(folder: str | os.PathLike) -> None:
    """Fail early (before any slow stage) when ``folder`` cannot take outputs.

    Creates nothing that outlives the call.
    """
    folder = Path(folder)
    created = _make_parents(folder)
    try:
        fd, probe = tempfile.mkstemp(prefix=STAGING_PREFIX, dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CaptureError(f"cannot write to output folder {folder}: {exc.strerror or exc}") from None
    finally:
        _remove_empty(created)


def check_output_file(path: str | os.PathLike, flag: str, suffixes: Iterable[str] = (),
                      protect: Iterable[str | os.PathLike] = ()) -> None:
    """Fail early (before any slow work) when the file ``path`` (given as ``flag``) could not
    be written: it is a folder, its suffix is not one of ``suffixes`` (any when empty), it
    is a protected file (the source clip), or its folder cannot be created or written.

    Creates nothing that outlives the call.
    """
    path = Path(path)
    suffixes = tuple(suffixes)
    if path.is_dir():
        example = path / f"out{suffixes[0]}" if suffixes else path / "out"
        raise CaptureError(f"{flag} {path}: is a folder; give the file to write (e.g. {example})")
    if suffixes and path.suffix.lower() not in suffixes:
        raise CaptureError(f"{flag} {path}: the file must end in {' or '.join(suffixes)}")
    if _same_file(path, [Path(p) for p in protect]):
        raise CaptureError(f"{flag} {path}: is the source clip or another output; choose another file name")
    try:
        check_writable(path.parent)
    except CaptureError as exc:
        raise CaptureError(f"{flag} {path}: {exc}") from None

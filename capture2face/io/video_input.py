"""The one video decoder every stage uses: PyAV (FFmpeg), frames streamed as RGB arrays.

Anything FFmpeg reads works (mp4, mov, mkv, avi, webm; H.264, HEVC, VP9, MJPEG, ...).

* **Timestamps** are the true presentation times, ``(pts - stream start) * time_base``, so
  variable-frame-rate clips (phones) keep their timing; the first frame of a normal clip
  is at 0.0. A frame without a pts gets the previous time plus one nominal frame period;
  times are forced to increase strictly (broken muxers sometimes repeat a pts).
* **Rotation**: phone clips store a display matrix (side data; the old ``rotate`` tag on
  older FFmpeg builds). Frames are rotated with ``np.rot90`` the way FFmpeg's own
  autorotation shows them, so width/height in :class:`VideoInfo` are the displayed size.
* **Damaged files**: a file FFmpeg cannot open, one with no video stream, or one where no
  frame decodes raises :class:`CaptureError`. When decoding fails part way (a truncated
  download), the frames before the damage are kept and a warning is logged on the
  ``capture2face`` logger naming how many frames were decoded: losing a clip's tail is
  better than losing the clip, and the warning says it happened. Code that must decide on
  damage (``run`` fails unless told to salvage) gets it as a typed :class:`ClipDamage`
  event from :func:`watch_damage`, never by reading the warning's text.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError

log = logging.getLogger("capture2face")

DEFAULT_FPS = 30.0


@dataclass(frozen=True)
class VideoInfo:
    """What a clip is, as displayed.

    Attributes:
        path: the file.
        width, height: displayed frame size in pixels (after rotation).
        fps: nominal frame rate (average rate; 30 when the container does not say).
        n_frames: frame count from the container, else duration * fps (an estimate:
            variable-frame-rate and damaged files may decode more or fewer).
        duration: seconds.
        rotation: counter-clockwise degrees applied to decoded frames (0, 90, 180, 270).
        codec: decoder name, e.g. "h264".
        n_frames_exact: True when ``n_frames`` is the container's own count, False when it
            is estimated from the duration.
    """

    path: str
    width: int
    height: int
    fps: float
    n_frames: int
    duration: float
    rotation: int
    codec: str
    n_frames_exact: bool = True


@dataclass(frozen=True)
class ClipDamage:
    """A clip whose decoding stopped early: the frames before the damage were yielded.

    Attributes:
        path: the clip.
        frames_decoded: frames yielded before the damage.
        frames_expected: the container's frame count (None when it does not say).
        reason: "decode_error" (FFmpeg failed part way) or "short" (fewer frames than the
            container lists).
        message: the warning logged for it (one line, for the user).
    """

    path: str
    frames_decoded: int
    frames_expected: int | None
    reason: str
    message: str


_damage_watchers: list[tuple[str | None, list[ClipDamage]]] = []
_damage_lock = threading.Lock()


@contextlib.contextmanager
def watch_damage(path: str | os.PathLike | None = None) -> Iterator[list[ClipDamage]]:
    """Collect the :class:`ClipDamage` events of :func:`iter_frames` (in any thread) while
    the block runs; ``path`` limits them to one clip. Yields the list they are appended to."""
    key = os.path.realpath(path) if path is not None else None
    events: list[ClipDamage] = []
    entry = (key, events)
    with _damage_lock:
        _damage_watchers.append(entry)
    try:
        yield events
    finally:
        with _damage_lock:
            _damage_watchers.remove(entry)


def _report_damage(damage: ClipDamage) -> None:
    log.warning("%s", damage.message)
    key = os.path.realpath(damage.path)
    with _damage_lock:
        for watched, events in _damage_watchers:
            if watched is None or watched == key:
                events.append(damage)


def _check_path(path: str | os.PathLike) -> Path:
    p = Path(path)
    if not p.exists():
        raise CaptureError(f"{p}: no such file")
    if p.is_dir():
        raise CaptureError(f"{p}: is a directory, not a video file")
    if p.stat().st_size == 0:
        raise CaptureError(f"{p}: the file is empty (0 bytes)")
    return p


def _open(p: Path):
    """Open the container and pick its video stream, with one-line errors."""
    import av

    try:
        container = av.open(str(p))
    except av.FFmpegError as exc:
        raise CaptureError(f"{p}: not a video FFmpeg can read ({_reason(exc)})") from None
    if not container.streams.video:
        kinds = sorted({s.type for s in container.streams})
        container.close()
        if not kinds:
            raise CaptureError(f"{p}: no streams found; the file is truncated or not a video")
        raise CaptureError(f"{p}: has no video stream (found {', '.join(kinds)} streams only)")
    stream = container.streams.video[0]
    stream.thread_type = "AUTO"  # frame + slice threads inside FFmpeg
    return container, stream


def _reason(exc: Exception) -> str:
    text = getattr(exc, "strerror", None) or str(exc)
    return text.strip().rstrip(".") or exc.__class__.__name__


def _too_large(width: int, height: int) -> bool:
    """FFmpeg's own limit on a frame's size (``av_image_check_size``: 8 bytes a pixel of the
    frame padded by 128 on each axis must stay under 2 GiB); it refuses larger ones as
    "invalid data"."""
    return 8 * (width + 128) * (height + 128) >= 2**31 - 1


def image_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) from a PNG's or a JPEG's header, without decoding it; None for
    another format or a header that does not say."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if head[:2] == b"\xff\xd8":
        return _jpeg_size(head)
    return None


def _jpeg_size(head: bytes) -> tuple[int, int] | None:
    """A JPEG's size from its first start-of-frame segment within ``head``."""
    i = 2
    while i + 9 <= len(head) and head[i] == 0xFF:
        marker, length = head[i + 1], int.from_bytes(head[i + 2:i + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return int.from_bytes(head[i + 7:i + 9], "big"), int.from_bytes(head[i + 5:i + 7], "big")
        i += 2 + length
    return None


def _undecodable(p: Path, exc: Exception) -> str:
    """The one line for a file whose first frame does not decode: an image too large for
    FFmpeg says so (its size and the limit); anything else is damaged."""
    size = image_size(p)
    if size is not None and _too_large(*size):
        return (f"{p}: the image is {size[0]}x{size[1]} pixels, too large to decode (FFmpeg's limit is "
                "about 268 million pixels, e.g. 16000x16000); scale it down")
    return f"{p}: no video frame could be decoded ({_reason(exc)}); the file is truncated or corrupt"


def _rotation_of(frame, stream) -> int:
    """Counter-clockwise display rotation in degrees, a multiple of 90."""
    deg = getattr(frame, "rotation", None)  # display-matrix side data (PyAV >= 14)
    if not deg:
        tag = stream.metadata.get("rotate")  # older FFmpeg: clockwise degrees
        deg = -float(tag) if tag else 0
    return int(round(float(deg) / 90.0)) * 90 % 360


def _fps_of(stream) -> float:
    for rate in (stream.average_rate, stream.guessed_rate, stream.base_rate):
        if rate and float(rate) > 0 and float(rate) < 1000:
            return float(rate)
    return DEFAULT_FPS


def _to_rgb(frame, rotation: int) -> np.ndarray:
    rgb = frame.to_ndarray(format="rgb24")
    if rotation:
        rgb = np.ascontiguousarray(np.rot90(rgb, k=rotation // 90))
    return rgb


def open_video(path: str | os.PathLike) -> VideoInfo:
    """Probe a clip (decodes its first frame to learn the rotation and prove it decodes).

    Raises:
        CaptureError: missing path, a directory, an empty file, not a video, no video
            stream (audio only), or no decodable frame.
    """
    p = _check_path(path)
    container, stream = _open(p)
    try:
        try:
            first = next(iter(container.decode(stream)), None)
        except Exception as exc:  # av.FFmpegError and friends: damaged data
            raise CaptureError(_undecodable(p, exc)) from None
        if first is None:
            raise CaptureError(f"{p}: the video stream has no frames")
        fps = _fps_of(stream)
        if stream.duration is not None and stream.time_base is not None:
            duration = float(stream.duration * stream.time_base)
        elif container.duration is not None:
            duration = container.duration / 1e6
        else:
            duration = 0.0
        n_frames = int(stream.frames) if stream.frames else max(1, int(round(duration * fps)))
        rotation = _rotation_of(first, stream)
        w, h = first.width, first.height
        if rotation in (90, 270):
            w, h = h, w
        return VideoInfo(
            path=str(p), width=int(w), height=int(h), fps=fps, n_frames=n_frames,
            duration=duration, rotation=rotation, codec=stream.codec_context.name,
            n_frames_exact=bool(stream.frames),
        )
    finally:
        container.close()


def iter_frames(path: str | os.PathLike, max_frames: int | None = None,
                rotate: bool = True) -> Iterator[tuple[float, np.ndarray]]:
    """Stream ``(t_seconds, rgb)`` pairs; ``rgb`` is (H, W, 3) uint8, displayed orientation.

    Args:
        max_frames: stop after this many frames (None: all).
        rotate: apply the rotation metadata (True) or yield frames as coded.

    Raises:
        CaptureError: as :func:`open_video`; also when no frame decodes at all. A failure
            after some frames ends the stream with a logged warning (see module doc).
    """
    p = _check_path(path)
    container, stream = _open(p)
    try:
        fps = _fps_of(stream)
        tb = stream.time_base or Fraction(1, 90000)
        start = stream.start_time
        rotation = None
        prev_t = None
        count = 0
        decoder = container.decode(stream)
        while max_frames is None or count < max_frames:
            try:
                frame = next(decoder)
            except StopIteration:
                break
            except Exception as exc:  # damaged data past this point
                if count == 0:
                    raise CaptureError(_undecodable(p, exc)) from None
                _report_damage(ClipDamage(
                    str(p), count, int(stream.frames or 0) or None, "decode_error",
                    f"{p}: decoding stopped after {count} frames ({_reason(exc)}); the rest of the file "
                    "is damaged or truncated and is ignored"))
                break
            if rotation is None:
                rotation = _rotation_of(frame, stream) if rotate else 0
            if frame.pts is not None:
                t = float((frame.pts - (start or 0)) * tb)
            else:
                t = prev_t + 1.0 / fps if prev_t is not None else 0.0
            if prev_t is not None and t <= prev_t:
                t = prev_t + 1e-6  # repeated or backwards pts: keep time strictly increasing
            prev_t = t
            count += 1
            yield t, _to_rgb(frame, rotation)
        if count == 0:
            raise CaptureError(f"{p}: the video stream has no frames")
        expected = int(stream.frames or 0)
        if max_frames is None and expected and count < expected * 0.98 - 1:
            _report_damage(ClipDamage(
                str(p), count, expected, "short",
                f"{p}: decoded {count} of the {expected} frames the container lists; the file is "
                "probably truncated"))
    finally:
        container.close()


def prefetch(iterable, depth: int = 8):
    """Run ``iterable`` (e.g. :func:`iter_frames`) in a background thread, ``depth`` items ahead.

    FFmpeg decodes and converts with the GIL released, so decoding overlaps the consumer's
    work (tracking, rendering). Exceptions are re-raised in the consumer; closing the
    returned generator stops the thread.
    """
    q: queue.Queue = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()
    done = object()

    def worker():
        try:
            for item in iterable:
                while not stop.is_set():
                    try:
                        q.put((item, None), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    break
        except BaseException as exc:  # handed to the consumer
            q.put((done, exc))
            return
        finally:
            close = getattr(iterable, "close", None)
            if stop.is_set() and close is not None:
                close()
        q.put((done, None))

    thread = threading.Thread(target=worker, name="capture2face-decode", daemon=True)
    thread.start()
    try:
        while True:
            item, exc = q.get()
            if item is done:
                if exc is not None:
                    raise exc
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # drain so a blocked put can see the stop flag
            with contextlib.suppress(queue.Empty):
                q.get(timeout=0.1)
        thread.join()


# ---- segments: a clip decoded from several places at once (capture2face.tracking.segments)
@dataclass(frozen=True)
class FrameTimes:
    """Every frame's presentation timestamp, from the packets (no decoding).

    Attributes:
        pts: (F,) int64 strictly increasing pts in ``time_base`` units, display order.
        start: the stream's start time (pts units) that :func:`iter_frames` subtracts.
        time_base: the video stream's time base.
    """

    pts: np.ndarray
    start: int
    time_base: Fraction


def frame_times(path: str | os.PathLike) -> FrameTimes | None:
    """The clip's frame timestamps read from its packets, or None when they cannot be
    trusted to name the decoded frames one to one: a packet without a pts, a repeated pts,
    a packet count other than the container's frame count, or unreadable (damaged) data.
    Such clips are decoded from the start only (:func:`iter_frames`)."""
    import av

    p = _check_path(path)
    container, stream = _open(p)
    try:
        pts = []
        for packet in container.demux(stream):
            if not packet.size:
                continue  # the demuxer's end-of-stream packet
            if packet.pts is None:
                return None
            pts.append(int(packet.pts))
        expected = int(stream.frames or 0)
        tb = stream.time_base or Fraction(1, 90000)
        start = int(stream.start_time or 0)
    except (av.FFmpegError, OSError):
        return None
    finally:
        container.close()
    out = np.sort(np.asarray(pts, np.int64))
    if not out.size or np.any(np.diff(out) <= 0) or (expected and out.size != expected):
        return None
    return FrameTimes(out, start, Fraction(tb))


def iter_segment(path: str | os.PathLike, first_pts: int, stop_pts: int | None,
                 rotation: int) -> Iterator[tuple[float, np.ndarray, int]]:
    """``(t_seconds, rgb, pts)`` of the frames with ``first_pts <= pts < stop_pts`` (None:
    to the end), decoded from the keyframe at or before ``first_pts``; times as
    :func:`iter_frames` gives them (for clips :func:`frame_times` accepts). Frames before
    ``first_pts`` are decoded (they are needed) but not converted to RGB.

    Raises:
        CaptureError: a frame without a pts, or data that does not decode (the caller
            falls back to decoding from the start).
    """
    p = _check_path(path)
    for seek in (first_pts > 0, False):
        container, stream = _open(p)
        try:
            tb = stream.time_base or Fraction(1, 90000)
            start = stream.start_time or 0
            if seek:
                container.seek(int(first_pts), backward=True, any_frame=False, stream=stream)
            first = True
            try:
                for frame in container.decode(stream):
                    if frame.pts is None:
                        raise CaptureError(f"{p}: a frame without a timestamp")
                    if first and seek and frame.pts > first_pts:
                        break  # the seek landed past the segment's start: decode from the start
                    first = False
                    if frame.pts < first_pts:
                        continue
                    if stop_pts is not None and frame.pts >= stop_pts:
                        return
                    yield float((frame.pts - start) * tb), _to_rgb(frame, rotation), int(frame.pts)
                else:
                    return
            except CaptureError:
                raise
            except Exception as exc:  # av.FFmpegError and friends: damaged data
                raise CaptureError(f"{p}: decoding failed ({_reason(exc)})") from None
        finally:
            container.close()

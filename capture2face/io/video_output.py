"""Streaming H.264 (yuv420p) .mp4 writer on PyAV; atomic (temp name, renamed on success).

RGB -> YUV 4:2:0 (BT.601, limited range, as swscale's default) is done by OpenCV, about 5x
faster than PyAV's swscale path for rgb24, and outside the GIL.

* **Timing**: frames get ``i / fps`` by default. Given the source's presentation times
  (``times``) that are not a constant rate, each frame keeps its own time instead (pts in
  a 1/90000 s time base), so a variable-frame-rate clip's output stays in sync with it.
* **Audio**: ``audio_from`` copies a source clip's first audio stream alongside the video,
  interleaved as the frames arrive (no second pass, no whole-clip buffer): stream copy
  for codecs MP4 carries well (AAC, MP3, AC-3, E-AC-3, ALAC), else re-encoded to AAC.
  Audio is aligned to the source's video start and cut at the written video's end.
"""

from __future__ import annotations

import contextlib
import os
import sys
from fractions import Fraction

import av
import cv2
import numpy as np

from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path


def frame_rate(fps: float | Fraction) -> Fraction:
    """Exact rate for a float fps: 29.97 -> 2997/100, 30000/1001 stays 30000/1001."""
    if isinstance(fps, Fraction):
        return fps
    rate = Fraction(fps).limit_denominator(1001)
    if rate <= 0:
        raise CaptureError(f"frame rate must be positive, got {fps}")
    return rate


VFR_TIME_BASE = Fraction(1, 90000)
COPY_AUDIO_CODECS = frozenset({"aac", "mp3", "ac3", "eac3", "alac"})


def is_constant_rate(times, fps: float | Fraction) -> bool:
    """True when presentation times ``times`` (seconds) are ``t0 + i / fps`` to within a
    tenth of a frame (and 2 ms): the clip is written at its constant rate, as before."""
    t = np.asarray(times, np.float64)
    if t.size < 2:
        return True
    period = 1.0 / float(fps)
    drift = np.abs((t - t[0]) - np.arange(t.size) * period)
    return bool(drift.max() <= min(0.1 * period, 0.002))


class _AudioCopy:
    """The source's first audio stream, muxed into an output container as video arrives.

    Output time 0 is the source's video start (its first frame), as in
    :func:`capture2face.io.video_input.iter_frames`; audio before it is dropped.
    """

    def __init__(self, source: str | os.PathLike, container) -> None:
        self.source = av.open(str(source))
        try:
            self.out = container
            streams = self.source.streams
            self.stream = streams.audio[0] if streams.audio else None
            self.done = self.stream is None
            if self.stream is None:
                return
            video = streams.video[0] if streams.video else None
            start = 0.0
            if video is not None and video.start_time is not None and video.time_base is not None:
                start = float(video.start_time * video.time_base)
            self.in_tb = self.stream.time_base or Fraction(1, self.stream.codec_context.sample_rate or 48000)
            self.offset = int(round(start / self.in_tb))
            name = self.stream.codec_context.codec.canonical_name  # "mp3", not the decoder "mp3float"
            self.copy = name in COPY_AUDIO_CODECS
            if self.copy:
                try:
                    self.out_stream = container.add_stream_from_template(self.stream)
                except ValueError:  # the container does not take this codec as is
                    self.copy = False
            if not self.copy:
                cc = self.stream.codec_context
                rate = int(cc.sample_rate or 48000)
                rate = rate if 8000 <= rate <= 96000 else 48000
                layout = "mono" if cc.channels == 1 else "stereo"
                self.out_stream = container.add_stream("aac", rate=rate)
                self.out_stream.layout = layout
                self.out_stream.bit_rate = 64000 * (1 if layout == "mono" else 2)
            self.packets = self.source.demux(self.stream)
            self.pending = None  # a packet read past the last pump's limit
        except BaseException:
            self.source.close()
            raise

    def pump(self, until: float) -> None:
        """Mux the source's audio that starts before ``until`` seconds (output time)."""
        while not self.done:
            packet = self.pending
            self.pending = None
            if packet is None:
                try:
                    packet = next(self.packets)
                except StopIteration:
                    self.done = True
                    break
                except av.FFmpegError:  # damaged audio past this point: keep what we have
                    self.done = True
                    break
                if packet.pts is None or packet.size == 0:
                    continue
            t = float((packet.pts - self.offset) * self.in_tb)
            if t >= until:
                self.pending = packet
                return
            end = t + float((packet.duration or 0) * self.in_tb)
            if end < 0 and packet.duration:
                continue  # wholly before the first video frame (one ending at 0 is the codec's priming)
            self._write(packet)

    def _write(self, packet) -> None:
        if self.copy:
            packet.pts -= self.offset
            if packet.dts is not None:
                packet.dts -= self.offset
            packet.stream = self.out_stream
            self.out.mux(packet)
            return
        try:
            frames = packet.decode()
        except av.FFmpegError:
            return
        for frame in frames:  # the encoder converts format, layout and rate itself
            if frame.pts is not None:
                frame.pts -= self.offset
                frame.time_base = self.in_tb
            for out in self.out_stream.encode(frame):
                self.out.mux(out)

    def finish(self, end: float) -> None:
        """Mux the audio up to ``end`` seconds and flush the encoder."""
        if self.stream is None:
            return
        self.pump(end)
        if not self.copy:
            for packet in self.out_stream.encode(None):
                self.out.mux(packet)

    def close(self) -> None:
        self.source.close()


class VideoWriter:
    """``with VideoWriter(path, fps, (W, H)) as out: out.write(frame)``.

    Frames (H, W, 3) uint8 RGB are encoded as they arrive, so memory does not grow with
    the clip's length. The file appears under ``path`` only when the ``with`` block ends
    without an exception; otherwise the temporary file is deleted.

    Args:
        times: the frames' presentation times in seconds (e.g. ``Track.times``); when they
            are not a constant ``fps``, frame ``i`` is shown at ``times[i] - times[0]``.
        audio_from: a clip whose audio (if any) is copied into the file (see module doc).
    """

    def __init__(self, path: str | os.PathLike, fps: float | Fraction, size: tuple[int, int], crf: int = 20,
                 preset: str = "medium", threads: int = 0, times=None,
                 audio_from: str | os.PathLike | None = None):
        width, height = int(size[0]), int(size[1])
        if width <= 0 or height <= 0 or width % 2 or height % 2:
            raise CaptureError(f"H.264 yuv420p needs an even, positive frame size; got {width}x{height}")
        self.path = path
        self.rate = frame_rate(fps)
        self.size = (width, height)
        self.crf = int(crf)
        self.preset = str(preset)  # x264 speed/size trade-off: ultrafast ... veryslow
        self.threads = int(threads)  # x264 threads; 0: x264 picks (1.5 per core)
        self.frames_written = 0
        self.times = None
        if times is not None and not is_constant_rate(times, self.rate):
            self.times = np.asarray(times, np.float64) - float(times[0])
        self._durations: dict[int, int] = {}  # pts -> duration of frames inside the encoder
        self._last_pts = -1
        self.audio_from = audio_from
        self.has_audio = False
        self._audio: _AudioCopy | None = None
        self._stack: contextlib.ExitStack | None = None
        self._container = None
        self._stream = None

    def __enter__(self) -> VideoWriter:
        self._stack = contextlib.ExitStack()
        try:
            tmp = self._stack.enter_context(atomic_path(self.path))
            self._container = av.open(str(tmp), mode="w")
            self._stack.callback(self._container.close)
            stream = self._container.add_stream("libx264", rate=self.rate)
            stream.width, stream.height = self.size
            stream.pix_fmt = "yuv420p"
            options = {"crf": str(self.crf), "preset": self.preset}
            if self.threads:
                options["threads"] = str(self.threads)
            if self.times is not None:  # each frame keeps its own time
                stream.time_base = VFR_TIME_BASE
                stream.codec_context.time_base = VFR_TIME_BASE
                # No B-frames: x264 would delay the dts of uneven frames by two frame steps,
                # and MP4's track (and edit list) duration would end short of the last frame.
                options["bf"] = "0"
            stream.options = options
            self._stream = stream
            if self.audio_from is not None:
                self._audio = _AudioCopy(self.audio_from, self._container)
                self._stack.callback(self._audio.close)
                self.has_audio = self._audio.stream is not None
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        return self

    def write(self, frame: np.ndarray) -> None:
        """Encode one (H, W, 3) uint8 RGB frame."""
        if self._stream is None:
            raise RuntimeError("VideoWriter.write outside its 'with' block")
        frame = np.asarray(frame)
        width, height = self.size
        if frame.shape != (height, width, 3) or frame.dtype != np.uint8:
            raise ValueError(f"expected a ({height}, {width}, 3) uint8 frame, got {frame.shape} {frame.dtype}")
        yuv = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2YUV_I420)  # (3H/2, W)
        video_frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        i = self.frames_written
        if self.times is not None:
            if i >= len(self.times):
                raise ValueError(f"frame {i} has no presentation time ({len(self.times)} given)")
            # strictly increasing (the decoder nudges a repeated pts by 1 us, less than a tick)
            video_frame.pts = max(int(round(self.times[i] / VFR_TIME_BASE)), self._last_pts + 1)
            self._last_pts = video_frame.pts
            video_frame.time_base = VFR_TIME_BASE
            # libx264 gives every packet one nominal frame's duration; MP4 keeps the last's
            self._durations[video_frame.pts] = max(1, int(round(self._frame_duration(i) / VFR_TIME_BASE)))
        for packet in self._stream.encode(video_frame):
            self._mux_video(packet)
        self.frames_written += 1
        if self._audio is not None:
            self._audio.pump(self._time(i))

    def _mux_video(self, packet) -> None:
        if self.times is not None and packet.pts is not None:
            duration = self._durations.pop(packet.pts, None)
            if duration:
                packet.duration = duration
        self._container.mux(packet)

    def _frame_duration(self, i: int) -> float:
        t = self.times
        if i + 1 < len(t):
            return float(t[i + 1] - t[i])
        return float(t[i] - t[i - 1]) if i > 0 else float(1 / self.rate)

    def _time(self, i: int) -> float:
        """Seconds at which frame ``i`` is shown."""
        if self.times is not None:
            return float(self.times[i])
        return float(i / self.rate)

    @property
    def duration(self) -> float:
        """Seconds of video written so far (the last frame's end)."""
        n = self.frames_written
        if n == 0:
            return 0.0
        if self.times is not None:
            return self._time(n - 1) + self._frame_duration(n - 1)
        return float(n / self.rate)

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                for packet in self._stream.encode():  # flush the encoder
                    self._mux_video(packet)
                if self._audio is not None:
                    self._audio.finish(self.duration)
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        finally:
            self._stream = None
        # Closes the container, then renames the temp file (or deletes it on an exception).
        return bool(self._stack.__exit__(exc_type, exc, tb))


"""Streaming H.264 (yuv420p) .mp4 writer on PyAV; atomic (temp name, renamed on success).

RGB -> YUV 4:2:0 (BT.601, limited range, as swscale's default) is done by OpenCV, about 5x
faster than PyAV's swscale path for rgb24, and outside the GIL."""

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


class VideoWriter:
    """``with VideoWriter(path, fps, (W, H)) as out: out.write(frame)``.

    Frames (H, W, 3) uint8 RGB are encoded as they arrive, so memory does not grow with
    the clip's length. The file appears under ``path`` only when the ``with`` block ends
    without an exception; otherwise the temporary file is deleted.
    """

    def __init__(self, path: str | os.PathLike, fps: float | Fraction, size: tuple[int, int], crf: int = 20,
                 preset: str = "medium", threads: int = 0):
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
        self._stack: contextlib.ExitStack | None = None
        self._container = None
        self._stream = None

    def __enter__(self) -> "VideoWriter":
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
            stream.options = options
            self._stream = stream
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
        for packet in self._stream.encode(video_frame):
            self._container.mux(packet)
        self.frames_written += 1

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                for packet in self._stream.encode():  # flush the encoder
                    self._container.mux(packet)
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        finally:
            self._stream = None
        # Closes the container, then renames the temp file (or deletes it on an exception).
        return bool(self._stack.__exit__(exc_type, exc, tb))


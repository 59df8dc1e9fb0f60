"""How a clip is tracked: :class:`TrackOptions`."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from typing import Any

from capture2face.errors import CaptureError
from capture2face.runtime.cores import free_cores
from capture2face.runtime.moved_options import keeps_moved_names
from capture2face.tracking.filtering import OneEuro
from capture2face.tracking.landmarker import LandmarkerOptions

#: TrackOptions' keywords of before it composed LandmarkerOptions, and where they went.
MOVED_TO_LANDMARKER = {name: ("landmarker", name) for name in (
    "face_model", "num_faces", "faces", "face", "min_detection_confidence", "min_presence_confidence",
    "min_tracking_confidence")}


@keeps_moved_names(MOVED_TO_LANDMARKER)
@dataclass(kw_only=True)
class TrackOptions:
    """How a clip is tracked (how each default was chosen, with its figures: docs/tuning.md).

    The old keywords of the landmarker's settings (``TrackOptions(face=1)``) still work, with
    a ``DeprecationWarning``: they now live in ``landmarker``.

    Attributes:
        landmarker: MediaPipe's :class:`~capture2face.tracking.landmarker.LandmarkerOptions`:
            the face model, which face is tracked (``faces``, ``face``; ``num_faces``: the
            most it looks for at once, several cost little) and its thresholds.
        neutral_frame: index of the neutral frame (None: each region's rest found in the
            clip, :mod:`.rest`).
        neutral_image: instead, a photo or still of the same actor at rest.
        neutral_clip: instead, a short take of the same actor at rest.
        calibration: the actor's calibration (:mod:`capture2face.calibration`): a
            range-of-motion take (a video), its ``actor.json``, or an ``ActorCalibration``.
            Tracking itself ignores it: ``pipeline`` learns or loads it and the clip's
            track carries it.
        max_gap_seconds: gaps up to this long are interpolated; longer ones hold.
        min_cutoff, beta, d_cutoff: One Euro filter of the head-coordinate landmarks
            (Hz, 1/cm, Hz); see :mod:`.filtering`.
        pose_min_cutoff, pose_beta: One Euro filter of the head pose (Hz, 1/cm).
        zero_phase: filter forward and backward (no lag; the whole clip is known).
        max_frames: track only the first N frames (None: all).
        workers: landmarkers tracking segments of the clip at once, each in a process of
            its own (:mod:`.segments`); None: one per free core; 1: one landmarker, this
            process. A clip shorter than two segments, or tracked with ``face``, is
            tracked by one. The Track is the same within MediaPipe's noise.
    """

    landmarker: LandmarkerOptions = field(default_factory=LandmarkerOptions)
    neutral_frame: int | None = None
    neutral_image: str | os.PathLike | None = None
    neutral_clip: str | os.PathLike | None = None
    calibration: Any = None
    max_gap_seconds: float = 0.25
    min_cutoff: float = 1.5
    beta: float = 1.0
    d_cutoff: float = 1.0
    pose_min_cutoff: float = 2.0
    pose_beta: float = 0.0
    zero_phase: bool = True
    max_frames: int | None = None
    workers: int | None = None

    def validate(self) -> None:
        """The face choice, workers and neutral frame: one line ``CaptureError`` each, named
        after the command line's flags. The one home of these bounds (``RunOptions``,
        ``FaceLandmarker`` and the CLI ask it); the neutral frame's upper bound needs the
        clip (:func:`capture2face.pipeline.preflight.check_neutral_frame`)."""
        if self.neutral_frame is not None and int(self.neutral_frame) < 0:
            raise CaptureError(f"--neutral-frame must be >= 0 (got {self.neutral_frame})")
        given = [flag for flag, v in (("--neutral-frame", self.neutral_frame), ("--neutral-image", self.neutral_image),
                                      ("--neutral-clip", self.neutral_clip)) if v is not None]
        if len(given) > 1:
            raise CaptureError(f"{' and '.join(given)}: give one rest (a frame, an image or a clip), not several")
        if isinstance(self.calibration, (str, os.PathLike)):
            _check_calibration_file(self.calibration)
        for flag, path, kind in (("--neutral-image", self.neutral_image, "an image file (a photo or still)"),
                                 ("--neutral-clip", self.neutral_clip, "a video file")):
            if path is not None and os.path.isdir(path):
                raise CaptureError(f"{flag} {os.fspath(path)}: is a folder; give {kind}")
            if path is not None and not os.path.isfile(path):
                raise CaptureError(f"{flag} {os.fspath(path)}: no such file")
        self.landmarker.validate()
        if self.workers is not None and int(self.workers) < 1:
            raise CaptureError(f"--track-workers must be >= 1 (got {self.workers})")

    def landmarker_options(self) -> LandmarkerOptions:
        """Deprecated: :attr:`landmarker`."""
        warnings.warn("TrackOptions.landmarker_options() is deprecated; use TrackOptions.landmarker",
                      DeprecationWarning, stacklevel=2)
        return self.landmarker

    def landmark_filter(self) -> OneEuro:
        return OneEuro(self.min_cutoff, self.beta, self.d_cutoff, self.zero_phase)

    def pose_filter(self) -> OneEuro:
        return OneEuro(self.pose_min_cutoff, self.pose_beta, self.d_cutoff, self.zero_phase)

    def n_workers(self) -> int:
        """Landmarkers at once (:attr:`workers`, None resolved to the free cores)."""
        return max(1, int(self.workers)) if self.workers is not None else free_cores()


def _check_calibration_file(path: str | os.PathLike) -> None:
    """``--calibration``: an existing file (a video or an ``actor.json``; read later)."""
    if os.path.isdir(path):
        raise CaptureError(f"--calibration {os.fspath(path)}: is a folder; give a range-of-motion take "
                           "(a video) or an actor.json")
    if not os.path.isfile(path):
        raise CaptureError(f"--calibration {os.fspath(path)}: no such file")

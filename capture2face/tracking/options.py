"""How a clip is tracked: :class:`TrackOptions`."""

from __future__ import annotations

import os
from dataclasses import dataclass

from capture2face.errors import CaptureError
from capture2face.runtime.cores import free_cores
from capture2face.tracking.filtering import OneEuro
from capture2face.tracking.landmarker import LandmarkerOptions


@dataclass
class TrackOptions:
    """How a clip is tracked (how each default was chosen, with its figures: docs/tuning.md).

    Attributes:
        face_model: ``face_landmarker.task`` path (None: $CAPTURE2FACE_FACE_MODEL, else the
            copy bundled in capture2face/models).
        neutral_frame: index of the neutral frame (None: each region's rest found in the
            clip, :mod:`.rest`).
        neutral_image: instead, a photo or still of the same actor at rest.
        neutral_clip: instead, a short take of the same actor at rest.
        num_faces: the most faces MediaPipe looks for (and counts) at once; 1: one face,
            no choice, no count. Several cost little: see :mod:`.landmarker`.
        faces: which face starts the track when several are in view: "largest" or
            "center" (nearest the image centre); the one continuing it is followed.
        face: instead, the face with this index (0-based, left to right) in the first
            frame with more than ``face`` faces (earlier frames count as faceless).
        min_detection_confidence, min_presence_confidence, min_tracking_confidence:
            MediaPipe's thresholds.
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

    face_model: str | os.PathLike | None = None
    neutral_frame: int | None = None
    neutral_image: str | os.PathLike | None = None
    neutral_clip: str | os.PathLike | None = None
    num_faces: int = 4
    faces: str = "largest"
    face: int | None = None
    min_detection_confidence: float = 0.5
    min_presence_confidence: float = 0.5
    min_tracking_confidence: float = 0.5
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
        for flag, path in (("--neutral-image", self.neutral_image), ("--neutral-clip", self.neutral_clip)):
            if path is not None and not os.path.isfile(path):
                raise CaptureError(f"{flag} {os.fspath(path)}: no such file")
        self.landmarker_options().validate()
        if self.workers is not None and int(self.workers) < 1:
            raise CaptureError(f"--track-workers must be >= 1 (got {self.workers})")

    def landmarker_options(self) -> LandmarkerOptions:
        return LandmarkerOptions(
            face_model=self.face_model, num_faces=self.num_faces, faces=self.faces, face=self.face,
            min_detection_confidence=self.min_detection_confidence,
            min_presence_confidence=self.min_presence_confidence,
            min_tracking_confidence=self.min_tracking_confidence,
        )

    def landmark_filter(self) -> OneEuro:
        return OneEuro(self.min_cutoff, self.beta, self.d_cutoff, self.zero_phase)

    def pose_filter(self) -> OneEuro:
        return OneEuro(self.pose_min_cutoff, self.pose_beta, self.d_cutoff, self.zero_phase)

    def n_workers(self) -> int:
        """Landmarkers at once (:attr:`workers`, None resolved to the free cores)."""
        return max(1, int(self.workers)) if self.workers is not None else free_cores()

"""``Track``: a clip's face, frame by frame, as the tracker saw it and head-stabilized.

Saved as ``track.npz`` (schema = the attributes below, one array each; lists of strings
as unicode arrays; written by :meth:`Track.save`, read by :meth:`Track.load`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from capture2face.io.npz import load_dataclass, save_dataclass

FORMAT = "capture2face.Track/1"


@dataclass
class Track:
    """Per-frame face landmarks of one clip. F frames, L = 478 landmarks, S = 52 scores.

    Attributes:
        times: (F,) float64 presentation time of each frame in seconds (true timestamps,
            so variable-frame-rate clips keep their timing).
        landmarks_px: (F, L, 2) float32 landmark positions in source pixels (x right,
            y down), after rotation metadata has been applied.
        landmarks_depth: (F, L) float32 MediaPipe's relative depth (z * width), pixels.
        landmarks_head: (F, L, 3) float32 landmarks in head coordinates (cm, canonical
            face-mesh frame: +x subject's left, +y up, +z out of the face), filtered.
            Head motion alone moves none of them.
        presence: (F,) bool, a face was detected in this frame.
        interpolated: (F,) bool, the frame's values were interpolated over a short gap.
        held: (F,) bool, the frame lies in a long gap: values hold the last pose.
        blendshapes: (F, S) float32 MediaPipe's blendshape scores in [0, 1].
        blendshape_names: S names (ARKit names, MediaPipe's spelling: "browInnerUp", ...).
        head_pose: (F, 4, 4) float32 head -> camera transform (cm), MediaPipe's facial
            transformation matrix (camera looks down -z, y up), filtered.
        neutral_frame: index of the frame taken as the neutral expression.
        width, height: source frame size in pixels (after rotation).
        fps: nominal frame rate of the source.
        source: path of the source clip.
        n_faces_max: the most faces seen in one frame.
        n_gaps: number of gaps (runs of frames without a face).
        n_long_gaps: gaps longer than the interpolation limit (flagged as held).
        camera_fov_y: vertical field of view (degrees) assumed for head_pose.
        rest_face: (L, 3) float32 the actor's whole face at rest, head coordinates
            (:class:`~capture2face.tracking.rest.ActorRest`); None: worked out from the
            clip when needed.
        rest_landmarks: (L, 3) float32 the same, each region from its own rest frames.
        rest_scores: (S,) float32 the scores at rest.
        rest_frames: (4, K) int32 the frames each region's rest took (rows: brows, eyes,
            mouth, face; -1 padded; all -1 for a rest from outside the clip).
        rest_source: where the rest came from ("clip", "frame N", "image PATH", "clip PATH",
            "calibration PATH").
        calibration: the actor's calibration from a range-of-motion take, as its JSON text
            (:mod:`capture2face.calibration`), or "" for none.
    """

    times: np.ndarray
    landmarks_px: np.ndarray
    landmarks_depth: np.ndarray
    landmarks_head: np.ndarray
    presence: np.ndarray
    interpolated: np.ndarray
    held: np.ndarray
    blendshapes: np.ndarray
    blendshape_names: list[str]
    head_pose: np.ndarray
    neutral_frame: int
    width: int
    height: int
    fps: float
    source: str = ""
    n_faces_max: int = 1
    n_gaps: int = 0
    n_long_gaps: int = 0
    camera_fov_y: float = 63.0
    rest_face: np.ndarray | None = None
    rest_landmarks: np.ndarray | None = None
    rest_scores: np.ndarray | None = None
    rest_frames: np.ndarray | None = None
    rest_source: str = ""
    calibration: str = ""

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])

    @property
    def tracked_frames(self) -> int:
        return int(self.presence.sum())

    def save(self, path: str | os.PathLike) -> None:
        save_dataclass(self, path, FORMAT)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Track:
        return load_dataclass(cls, path, FORMAT)

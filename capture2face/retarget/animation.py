"""``Animation``: the character's performance, frame by frame. Saved as animation.npz."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from capture2face.io.npz import load_dataclass, save_dataclass

FORMAT = "capture2face.Animation/1"


@dataclass
class Animation:
    """Per-frame character state. F frames, B bones, M morphs, P reference poses,
    R regions, Z = 8 zones, S = 52 MediaPipe blendshapes.

    Attributes:
        times: (F,) float64 seconds.
        fps: nominal frame rate.
        bone_names: B names (the rig's, bone 0 = head).
        bone_positions: (F, B, 3) float32 bone positions in head coordinates (cm).
        head_pose: (F, 4, 4) float32 head -> camera transform (cm), from the track.
        blend_names: M morph names (the rig's).
        blend_weights: (F, M) float32 morph weights in [0, 1].
        pose_names: P reference-pose names (includes "stretch" and "compress").
        influences: (F, P, B) float32 per-bone reference-pose influences in [0, 1]
            after bone grouping (Dutreve §5.1).
        rest_influence: (F, B) float32 max(0, 1 - sum_k influence_k).
        region_names: R names (forehead, glabella, crows_feet_left, ...).
        region_influence: (F, R, P) float32 mean per-vertex influence over each region.
        zone_names: the 8 Jimenez zones.
        zone_weights: (F, 8) float32 zone weights for the ``zones`` driver, in [-1, 1]
            (+ compress map, - stretch map, Oat's convention).
        mediapipe_blendshapes: (F, S) float32 the tracker's own scores (baseline).
        mediapipe_blendshape_names: S names.
        presence: (F,) bool, the source frame had a face.
        character: name of the rig the animation was retargeted onto.
        arkit_names: S names of the ARKit curves (MediaPipe's order and spelling).
        arkit_weights: (F, S) float32 ARKit curves in [0, 1] with ARKit meaning (0 at rest,
            1 at the full pose; :func:`capture2face.retarget.arkit.arkit_curves`), or None
            in files written before they existed.
        eye_rotation: (F, 2, 2) float32 gaze in head coordinates, degrees:
            ``[f, eye, (yaw, pitch)]``, eye 0 the subject's right (tracker landmarks
            468-472), eye 1 the left (473-477); yaw > 0 towards the subject's left (+x),
            pitch > 0 down (Live Link Face's signs; rotation Ry(yaw) Rx(pitch) of the
            straight-ahead +z gaze). From the tracked irises
            (:func:`capture2face.retarget.gaze.eye_rotation`); None in files written
            before it existed.
    """

    times: np.ndarray
    fps: float
    bone_names: list[str]
    bone_positions: np.ndarray
    head_pose: np.ndarray
    blend_names: list[str]
    blend_weights: np.ndarray
    pose_names: list[str]
    influences: np.ndarray
    rest_influence: np.ndarray
    region_names: list[str]
    region_influence: np.ndarray
    zone_names: list[str]
    zone_weights: np.ndarray
    mediapipe_blendshapes: np.ndarray
    mediapipe_blendshape_names: list[str]
    presence: np.ndarray
    character: str = ""
    arkit_names: list[str] = field(default_factory=list)
    arkit_weights: np.ndarray | None = None
    eye_rotation: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])

    def save(self, path: str | os.PathLike) -> None:
        save_dataclass(self, path, FORMAT)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Animation:
        return load_dataclass(cls, path, FORMAT)

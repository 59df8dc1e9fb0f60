"""Ground truth of a synthetic performance, saved beside the video as ``<stem>.truth.npz``."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from capture2face.camera import project
from capture2face.io.npz import load_dataclass, save_dataclass
from capture2face.rig.arkit_names import is_automatic
from capture2face.rig.deform import deform
from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.rig.feature_points import feature_positions
from capture2face.rig.influences import region_influence, rig_influences, zone_weights
from capture2face.topology import N_MESH

FORMAT = "capture2face.SyntheticTruth/1"

# A frame counts as showing the face when at least this fraction of the canonical
# landmarks project inside the image (and in front of the camera).
VISIBLE_FRACTION = 0.5
N_CANONICAL = N_MESH


@dataclass
class SyntheticTruth:
    """What was rendered, frame by frame. F frames, B bones, M morphs, L = 478 tracker
    landmarks, P reference poses, R regions, 8 zones.

    Schema of ``<stem>.truth.npz`` (one array per attribute, lists of strings as unicode
    arrays, written by :meth:`save`, read by :meth:`load`):

    Attributes:
        times: (F,) float64 seconds (frame f at f / fps, as the video's timestamps).
        fps: frame rate of the video.
        width, height: video size in pixels.
        fov_y: vertical field of view of the camera, degrees (OpenGL camera at the origin
            looking down -z).
        variant: the default avatar variant rendered ("" for the base avatar).
        bone_names: B names (bone 0 = "head").
        bone_positions: (F, B, 3) float32 bone positions, head coordinates (cm).
        blend_names: M morph names.
        blend_weights: (F, M) float32 morph weights in [0, 1].
        head_pose: (F, 4, 4) float32 head -> camera transform (cm).
        landmarks_head: (F, L, 3) float32 the deformed mesh vertex under each tracker
            landmark (morphs then skinning), head coordinates; NaN where the rig has no
            vertex for the landmark (``rig.landmark_vertices == -1``).
        landmarks_px: (F, L, 2) float32 their projection into the image (x right, y down,
            pixel centres at +0.5), ``camera.project``; NaN where landmarks_head is.
        face_visible: (F,) bool, at least half the canonical 468 landmarks project inside
            the image in front of the camera.
        pose_names: P reference-pose names.
        influences: (F, P, B) float32 grouped per-bone pose influences of the true bones
            (``rig.influences.rig_influences``, Dutreve §5.1).
        region_names: R region names.
        region_influence: (F, R, P) float32 mean per-vertex influence over each region.
        zone_names: the 8 zone names.
        zone_weights: (F, 8) float32 zone weights from the true blend weights, [-1, 1].
        light_direction: (F, 3) float32 unit vector towards the light, camera coordinates.
        key_pose: (F,) int8 -1 on free frames, 0 on frames held exactly at neutral, 1 + p
            on frames held exactly at reference pose p.
        head_angles: (F, 3) float32 yaw, pitch, roll (degrees) of the head.
        eye_rotation: (F, 2, 2) float32 yaw, pitch (degrees) of the right and left eye
            (``Animation.eye_rotation``'s convention); None in files written before gaze.
        wrinkles: the wrinkle driver the video was rendered with.
        actor: the character rendered ("" for the default avatar, ``variant`` says which);
            its ``blend_names`` are its morphs (an ARKit actor's bones stay at rest and its
            ``influences`` are those of its automatic feature points,
            :func:`capture2face.rig.feature_points.feature_positions`).
    """

    times: np.ndarray
    fps: float
    width: int
    height: int
    fov_y: float
    variant: str
    bone_names: list[str]
    bone_positions: np.ndarray
    blend_names: list[str]
    blend_weights: np.ndarray
    head_pose: np.ndarray
    landmarks_head: np.ndarray
    landmarks_px: np.ndarray
    face_visible: np.ndarray
    pose_names: list[str]
    influences: np.ndarray
    region_names: list[str]
    region_influence: np.ndarray
    zone_names: list[str]
    zone_weights: np.ndarray
    light_direction: np.ndarray
    key_pose: np.ndarray
    head_angles: np.ndarray
    wrinkles: str = "auto"
    eye_rotation: np.ndarray | None = None
    actor: str = ""

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])

    def pose_frames(self, name: str) -> np.ndarray:
        """Indices of the frames held exactly at reference pose ``name`` (or "neutral")."""
        label = 0 if name == "neutral" else 1 + self.pose_names.index(name)
        return np.flatnonzero(self.key_pose == label)

    def save(self, path: str | os.PathLike) -> None:
        save_dataclass(self, path, FORMAT)

    @classmethod
    def load(cls, path: str | os.PathLike) -> SyntheticTruth:
        return load_dataclass(cls, path, FORMAT)


def truth_path(video_path: str | os.PathLike) -> str:
    """``clip.mp4`` -> ``clip.truth.npz`` (beside the video)."""
    root, _ = os.path.splitext(os.fspath(video_path))
    return root + ".truth.npz"


def deformed_landmarks(rig: FaceRig, bone_positions: np.ndarray, blend_weights: np.ndarray,
                       chunk: int = 64, eye_rotation: np.ndarray | None = None) -> np.ndarray:
    """(F, B, 3), (F, M) [, (F, 2, 2) gaze] -> (F, L, 3) float32 deformed landmark
    vertices (NaN where absent).

    Uses the CPU reference ``rig.deform.deform`` (the renderer is tested against it),
    ``chunk`` frames at a time to bound memory.
    """
    lv = rig.landmark_vertices
    out = np.full((len(bone_positions), len(lv), 3), np.nan, np.float32)
    have = lv >= 0
    for s in range(0, len(bone_positions), chunk):
        eyes = None if eye_rotation is None else eye_rotation[s:s + chunk]
        pos, _ = deform(rig, bone_positions[s:s + chunk], blend_weights[s:s + chunk], eyes)
        out[s:s + chunk, have] = (pos[:, lv[have]] if rig.landmark_faces is None
                                  else landmark_points(rig, pos, np.flatnonzero(have)))
    return out


def compute_truth(rig: FaceRig, perf, width: int, height: int, variant: str | None = None,
                  wrinkles: str = "auto", actor: str = "") -> SyntheticTruth:
    """Everything a test or benchmark compares against, from a ``Performance`` (``actor``:
    the rendered character's name, "" for the default avatar)."""
    eyes = getattr(perf, "eye_rotation", None)
    landmarks_head = deformed_landmarks(rig, perf.bone_positions, perf.blend_weights, eye_rotation=eyes)
    landmarks_px = project(landmarks_head, perf.head_pose, perf.fov_y, (width, height)).astype(np.float32)
    canon = landmarks_px[:, :N_CANONICAL]
    # project() gives NaN behind the camera; NaN compares False, so those count as outside.
    inside = (canon[..., 0] >= 0) & (canon[..., 0] < width) & (canon[..., 1] >= 0) & (canon[..., 1] < height)
    # Automatic feature points (an ARKit character's) are where its morphs carry them.
    influences = rig_influences(feature_positions(rig, perf.blend_weights) if is_automatic(rig)
                                else perf.bone_positions, rig)
    return SyntheticTruth(
        times=perf.times.astype(np.float64),
        fps=float(perf.fps),
        width=int(width),
        height=int(height),
        fov_y=float(perf.fov_y),
        variant=variant or "",
        bone_names=list(rig.bone_names),
        bone_positions=perf.bone_positions.astype(np.float32),
        blend_names=list(rig.morph_names),
        blend_weights=perf.blend_weights.astype(np.float32),
        head_pose=perf.head_pose.astype(np.float32),
        landmarks_head=landmarks_head,
        landmarks_px=landmarks_px,
        face_visible=inside.mean(1) >= VISIBLE_FRACTION,
        pose_names=list(rig.pose_names),
        influences=influences,
        region_names=list(rig.region_names),
        region_influence=region_influence(influences, rig),
        zone_names=list(rig.zone_names),
        zone_weights=zone_weights(perf.blend_weights, rig.zone_table),
        light_direction=perf.light_direction.astype(np.float32),
        key_pose=perf.key_pose.astype(np.int8),
        head_angles=perf.head_angles.astype(np.float32),
        wrinkles=wrinkles,
        eye_rotation=None if eyes is None else np.asarray(eyes, np.float32),
        actor=actor,
    )


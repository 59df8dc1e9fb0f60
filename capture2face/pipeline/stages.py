"""``run``'s stages, each callable on its own: track, retarget, export; the character's
camera poses."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from capture2face.calibration.attach import attach
from capture2face.camera import face_centre_and_height, framing_pose
from capture2face.errors import CaptureError
from capture2face.export.livelink import write_livelink_csv
from capture2face.gltf import export_glb
from capture2face.gltf.character import export_character_animation
from capture2face.gltf.container import CHARACTER_SUFFIXES
from capture2face.io.video_input import open_video
from capture2face.pipeline.calibration import is_calibration_file, resolve_calibration
from capture2face.pipeline.options import RunOptions
from capture2face.retarget import RetargetOptions, retarget
from capture2face.rig.arkit_names import drive_mode
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.cores import free_cores
from capture2face.tracking import track_clip
from capture2face.tracking.segments import MIN_SEGMENT_FRAMES, SegmentWorkers


def track_stage(clip: str | os.PathLike, options: RunOptions, progress: bool = True,
                workdir: str | os.PathLike | None = None, workers=None, info=None):
    """Pass 1: the clip's :class:`~capture2face.tracking.track.Track` (with ``workdir``,
    its landmarks stay in files there: memory does not grow with the clip's length;
    ``workers``: :func:`start_track_workers`' processes; ``info``: the clip's
    :func:`~capture2face.io.video_input.open_video` probe, if already made). With
    ``options.track.calibration`` (an ``ActorCalibration``, or a file resolved now) the
    track carries it (:func:`~capture2face.calibration.attach.attach`)."""
    calibration = resolve_calibration(options.track, progress)
    track = track_clip(clip, options.track, progress=progress, workdir=workdir, workers=workers,
                       info=info)
    return track if calibration is None else attach(track, calibration)


def start_track_workers(clip: str | os.PathLike, options: RunOptions):
    """The segment-tracking processes ``run`` will use for ``clip``, started now so that
    their start-up (Python, MediaPipe, the model) overlaps the checks before tracking;
    None when the clip will be tracked by one landmarker (too short, ``--face``, one
    core, or a clip that does not open: the checks report that), or when a calibration
    take is learned first (tracked with workers of its own; the clip's start after it)."""
    track = options.track
    n = track.n_workers()
    if n < 2 or track.landmarker.face is not None or _learns_a_take(track.calibration):
        return None
    try:
        frames = open_video(clip).n_frames
    except CaptureError:
        return None
    k = min(n, frames // MIN_SEGMENT_FRAMES)
    return SegmentWorkers(k - 1, track.landmarker) if k >= 2 else None


def _learns_a_take(calibration) -> bool:
    return isinstance(calibration, (str, os.PathLike)) and not is_calibration_file(calibration)


def retarget_stage(track, rig: FaceRig, options: RetargetOptions | None = None):
    """Pass 2: the :class:`~capture2face.retarget.animation.Animation` of ``rig``
    (``options``: :attr:`RunOptions.retarget`; None: the defaults)."""
    return retarget(track, rig, options or RetargetOptions())


def export_stage(rig: FaceRig, animation, folder: str | os.PathLike, track=None, character: Any = None) -> None:
    """animation.npz, animation.glb and livelink.csv into ``folder`` (``track``: the
    clip's Track, whose MediaPipe scores fill Live Link columns the rig has no morph for;
    None uses the animation's copy of them). ``character``: the :attr:`RunOptions.character`
    the rig came from; a user's ARKit .glb gets its own file back, animated
    (:mod:`capture2face.gltf.character`), any other rig the FaceRig's export."""
    folder = Path(folder)
    animation.save(folder / "animation.npz")
    source = _character_file(character)
    if source is not None and drive_mode(rig) == "arkit":

        export_character_animation(source, rig, animation, folder / "animation.glb")
    else:
        export_glb(rig, folder / "animation.glb", animation=animation)
    write_livelink_csv(animation, track, folder / "livelink.csv")


def _character_file(character: Any) -> Path | None:
    """The .glb / .gltf / .vrm a character option names, or None (built-in, .npz, a FaceRig)."""
    if character is None or isinstance(character, FaceRig):
        return None
    path = Path(os.fspath(character))
    return path if path.suffix.lower() in CHARACTER_SUFFIXES and path.is_file() else None


def avatar_head_poses(rig: FaceRig, head_pose: np.ndarray, fov_y_degrees: float) -> np.ndarray:
    """(F, 4, 4) camera poses for the character: the tracked head rotation, with the face
    kept centred and framed (the source's camera distance means nothing for the rig).

    Args:
        head_pose: (F, 4, 4) tracked head -> camera transforms.
    """
    centre = face_centre_and_height(rig)[0]
    # framing_pose without rotation puts the face centre at (0, 0, -distance); keep it
    # there whatever the rotation.
    target = framing_pose(rig, fov_y_degrees=fov_y_degrees)[:3, 3] + centre
    rot = np.asarray(head_pose, np.float64)[:, :3, :3]
    if getattr(rig, "head_weights", None) is not None:
        # The head joint turns (avatar_head_rotations), the camera and the body stay.
        rot = np.broadcast_to(np.eye(3), rot.shape)
    poses = np.tile(np.eye(4), (len(rot), 1, 1))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = target - rot @ centre
    return poses


def avatar_head_rotations(rig: FaceRig, head_pose: np.ndarray) -> np.ndarray | None:
    """(F, 3, 3) float32 head-joint rotations for a character with a head joint
    (``FaceRig.head_weights``; :attr:`FrameState.head_rotation
    <capture2face.render.renderer.FrameState.head_rotation>`), else None: the head
    rotation turns the whole character (:func:`avatar_head_poses`)."""
    if getattr(rig, "head_weights", None) is None:
        return None
    return np.ascontiguousarray(np.asarray(head_pose, np.float32)[:, :3, :3])


def encoder_threads(software_gl: bool, cores: int | None = None) -> int:
    """x264 threads for each of ``run``'s two encoders. A software rasterizer (llvmpipe
    runs one thread per core) and small machines: one each, in threads of their own (x264's
    pool would take the cores the rasterizer needs). With a GPU drawing, the cores beyond
    the GL thread, decoding and compositing encode (x264 alone does ~150 fps at 512x512
    on one core, and run's compare.mp4 is three frames wide)."""
    cores = free_cores() if cores is None else int(cores)
    if software_gl or cores <= 4:
        return 1
    return max(1, min(8, (cores - 2) // 2))

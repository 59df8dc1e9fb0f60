"""Synthetic performances with ground truth (tests, ``capture2face eval``, the sample clip).

``synthesize(path, SynthOptions(...))`` renders the default avatar through a smooth random
performance (``synth.trajectories``) and writes ``clip.mp4`` plus ``clip.truth.npz``
(``synth.truth.SyntheticTruth``) beside it, both atomically. ``synthesize(..., actor=rig)``
renders any ARKit character instead, through a random ARKit performance (``synth.actor``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from tqdm import tqdm

from capture2face.errors import CaptureError
from capture2face.io.video_output import VideoWriter
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig
from capture2face.synth.actor import random_arkit_performance, rom_performance, with_turning_eyes
from capture2face.synth.trajectories import (
    DEFAULT_FOV_Y,
    Performance,
    random_performance,
)
from capture2face.synth.truth import SyntheticTruth, compute_truth, truth_path

__all__ = [
    "Performance",
    "SynthOptions",
    "SyntheticClip",
    "SyntheticTruth",
    "actor_rig",
    "random_arkit_performance",
    "random_performance",
    "render_performance",
    "synthesize",
    "truth_path",
]


@dataclass
class SynthOptions:
    """What to render.

    Attributes:
        frames: number of frames.
        seed: random seed; the same seed gives the same clip and truth.
        size: width = height in pixels (even, for H.264 yuv420p).
        fps: frame rate.
        head_motion: move the head (False: frontal, centred).
        expression: animate the face (False: one mild expression, head motion only).
        face_exit: the head leaves the frame for about a second mid-clip.
        variant: default avatar variant (None: the base avatar; "wide": the other one).
        wrinkles: wrinkle driver the video is rendered with.
        fov_y: camera field of view (degrees); MediaPipe's pose model assumes 63.
        start: "rest" (the clip starts on the neutral hold), "held" (one expression held
            for the first seconds) or "raised" (the brows raised on most frames, from frame
            0); the neutral hold is mid-clip for the last two (``random_performance``).
        rom: an ``actor`` performs the range-of-motion protocol instead of a random
            performance (:func:`~capture2face.synth.actor.rom_performance`; ``frames`` is
            the protocol's length).
    """

    frames: int = 150
    seed: int = 0
    size: int = 512
    fps: float = 30.0
    head_motion: bool = True
    expression: bool = True
    face_exit: bool = False
    variant: str | None = None
    wrinkles: str = "auto"
    fov_y: float = DEFAULT_FOV_Y
    start: str = "rest"
    rom: bool = False


@dataclass
class SyntheticClip:
    video_path: str
    truth_path: str
    truth: SyntheticTruth


def make_performance(rig, options: SynthOptions) -> Performance:
    """The performance ``synthesize`` renders for ``options``."""
    return random_performance(
        rig, options.frames, seed=options.seed, fps=options.fps, head_motion=options.head_motion,
        expression=options.expression, face_exit=options.face_exit, fov_y=options.fov_y, start=options.start,
    )


def actor_rig(actor: FaceRig) -> FaceRig:
    """The rig an ARKit actor is rendered and measured with: ``actor`` with turning eyes
    (:func:`~capture2face.synth.actor.with_turning_eyes`), so the gaze is seen."""
    return with_turning_eyes(actor)


def _check_actor_options(options: SynthOptions) -> None:
    if options.variant is not None:
        raise CaptureError("--variant renders a built-in avatar; leave it out with --actor")
    if options.start != "rest" or not options.expression or options.face_exit:
        raise CaptureError("an --actor performance starts at rest, with expression, and keeps the face in frame")


def render_performance(truth: SyntheticTruth, renderer, frames=None):
    """Yield the (H, W, 3) uint8 frames of ``truth`` (all, or the indices ``frames``)
    rendered by an open ``Renderer`` of the same rig."""
    for f in range(truth.n_frames) if frames is None else frames:
        yield renderer.render(FrameState(
            bone_positions=truth.bone_positions[f],
            blend_weights=truth.blend_weights[f],
            head_pose=truth.head_pose[f],
            influences=truth.influences[f],
            zone_weights=truth.zone_weights[f],
            light_direction=truth.light_direction[f],
            eye_rotation=None if truth.eye_rotation is None else truth.eye_rotation[f],
        ))


def synthesize(path: str | os.PathLike, options: SynthOptions | None = None, progress: bool = True,
               actor: FaceRig | None = None) -> SyntheticClip:
    """Render a synthetic performance to ``path`` (.mp4) and its truth to ``<stem>.truth.npz``.

    ``actor``: an ARKit character to render (see :func:`actor_rig`; its performance:
    :func:`~capture2face.synth.actor.random_arkit_performance`), or None: the default avatar
    (``options.variant``) through :func:`make_performance`.

    Frames stream straight to the encoder, so memory does not grow with the clip's length.
    """
    options = options or SynthOptions()
    if options.size < 64 or options.size % 2:
        raise CaptureError(f"--size must be an even number of pixels >= 64 (got {options.size})")
    if options.rom and actor is None:
        raise CaptureError("--rom needs an ARKit character as the --actor")
    if actor is None:
        rig = default_avatar(variant=options.variant)
        perf = make_performance(rig, options)
        truth = compute_truth(rig, perf, options.size, options.size, options.variant, options.wrinkles)
    else:
        _check_actor_options(options)
        rig = actor_rig(actor)
        if options.rom:
            perf = rom_performance(rig, options.seed, options.fps, options.head_motion, options.fov_y)
        else:
            perf = random_arkit_performance(rig, options.frames, options.seed, options.fps, options.head_motion,
                                            options.fov_y)
        truth = compute_truth(rig, perf, options.size, options.size, None, options.wrinkles, actor=rig.name)
    video_path, tpath = os.fspath(path), truth_path(path)
    render_opts = RenderOptions(size=options.size, wrinkles=options.wrinkles, fov_y_degrees=options.fov_y)
    with Renderer.create_from_options(rig, render_opts) as renderer, \
            VideoWriter(video_path, options.fps, (options.size, options.size)) as out:
        frames = render_performance(truth, renderer)
        for frame in tqdm(frames, total=truth.n_frames, desc="synth", unit="frame", disable=not progress):
            out.write(frame)
        truth.save(tpath)  # inside the block: an interrupted render leaves neither file
    return SyntheticClip(video_path=video_path, truth_path=tpath, truth=truth)

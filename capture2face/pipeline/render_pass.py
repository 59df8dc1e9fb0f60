"""``run``'s render pass: avatar.mp4 and compare.mp4, its stages overlapped."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture2face.errors import raise_if_interrupted
from capture2face.io.video_input import iter_frames
from capture2face.io.video_output import VideoWriter
from capture2face.pipeline.compose import SourceFitter, compare_frame
from capture2face.pipeline.options import RunOptions, run_render_options
from capture2face.pipeline.stages import (
    avatar_head_poses,
    avatar_head_rotations,
    encoder_threads,
)
from capture2face.render import FrameState, Renderer
from capture2face.render.context import software_gl
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.overlap import StageGroup


class RenderPass:
    """Pass 3 of one clip: avatar.mp4 and compare.mp4 into ``folder``, stages overlapped.

    One draw per frame gives both the character and its wrinkle-influence view (a second
    colour attachment); the GL thread (the one calling :meth:`run`, which owns the
    context) only draws and reads back, while worker threads decode the source again
    (:meth:`decode_source`), compose compare.mp4 frames and run the two H.264 encoders
    (:meth:`encode_avatar`, :meth:`encode_compare`).

    Args:
        keep_frames: indices of frames to hand back as images (report.html's poster
            frames): compare.mp4's frames, or avatar.mp4's without ``options.compare``.
    """

    def __init__(self, clip: str | os.PathLike, track, animation, rig: FaceRig, folder: str | os.PathLike,
                 options: RunOptions, keep_frames=()) -> None:
        self.clip, self.track, self.animation, self.rig = clip, track, animation, rig
        self.folder = Path(folder)
        self.options = options
        self.n = animation.n_frames
        self.size = int(options.render.size)
        self.fps = float(track.fps)
        self.render_options = run_render_options(options)
        self.poses = avatar_head_poses(rig, animation.head_pose, self.render_options.fov_y_degrees).astype(np.float32)
        self.turns = avatar_head_rotations(rig, animation.head_pose)
        self.fitter = SourceFitter(track.width, track.height, self.size)
        self.threads = encoder_threads(software_gl())
        self.keep = {int(i) for i in keep_frames}
        self.kept: dict[int, np.ndarray] = {}
        # The source's frame times (a variable-rate clip keeps them) and its audio.
        self.times = np.asarray(track.times[:self.n], np.float64)
        self.audio_from = clip if options.audio else None

    def frame_state(self, i: int) -> FrameState:
        """What the renderer draws for frame ``i``."""
        anim = self.animation
        return FrameState(
            bone_positions=anim.bone_positions[i], blend_weights=anim.blend_weights[i],
            head_pose=self.poses[i], influences=anim.influences[i], zone_weights=anim.zone_weights[i],
            head_rotation=None if self.turns is None else self.turns[i],
            eye_rotation=None if anim.eye_rotation is None else anim.eye_rotation[i],
        )

    def _writer(self, name: str, width: int) -> VideoWriter:
        opts = self.options
        return VideoWriter(self.folder / name, self.fps, (width, self.size), crf=opts.crf, preset=opts.preset,
                           threads=self.threads, times=self.times, audio_from=self.audio_from)

    def encode_avatar(self, frames) -> None:
        with self._writer("avatar.mp4", self.size) as out:
            for frame in frames:
                out.write(frame)

    def decode_source(self, sink) -> None:
        for _, rgb in iter_frames(self.clip, max_frames=self.n):
            sink.put(rgb)
        sink.close()

    def encode_compare(self, panels, sources) -> None:
        track = self.track
        src = iter(sources)
        with self._writer("compare.mp4", 3 * self.size) as out:
            for i, (avatar, heat) in enumerate(panels):
                frame = compare_frame(self.fitter, next(src, None), track.landmarks_px[i], bool(track.presence[i]),
                                      avatar, heat)
                out.write(frame)
                if i in self.keep:
                    self.kept[i] = frame
            for _ in src:  # drain, so the decoder is never left blocked
                pass

    def run(self, progress: bool = True) -> dict:
        """Render every frame.

        Returns:
            ``{"render_s": GL thread busy seconds, "frames": n, "kept": {index: (H, W, 3) RGB}}``.
        """
        compare = self.options.compare
        q = max(2, int(self.options.queue_frames))
        busy = 0.0
        with StageGroup() as group, contextlib.ExitStack() as stack:
            avatar_q = group.channel(q)
            group.spawn("encode-avatar", self.encode_avatar, avatar_q)
            if compare:
                source_q, panel_q = group.channel(q), group.channel(q)
                group.spawn("decode", self.decode_source, source_q)
                group.spawn("encode-compare", self.encode_compare, panel_q, source_q)
            renderer = stack.enter_context(Renderer.create_from_options(self.rig, self.render_options))
            bar = stack.enter_context(tqdm(total=self.n, disable=not progress, unit="frame", desc="rendering",
                                           leave=False))
            for i in range(self.n):
                raise_if_interrupted()
                t0 = time.perf_counter()
                state = self.frame_state(i)
                if compare:
                    image, heat = renderer.render_with_influence(state)
                else:
                    image = renderer.render(state)
                busy += time.perf_counter() - t0
                if i in self.keep and not compare:
                    self.kept[i] = image.copy()
                avatar_q.put(image)
                if compare:
                    panel_q.put((image, heat))
                bar.update(1)
            avatar_q.close()
            if compare:
                panel_q.close()
        return {"render_s": busy, "frames": self.n, "kept": self.kept}


def render_stage(clip: str | os.PathLike, track, animation, rig: FaceRig, folder: str | os.PathLike,
                 options: RunOptions, progress: bool = True, keep_frames=()) -> dict:
    """Pass 3: avatar.mp4 and compare.mp4 into ``folder`` (:class:`RenderPass`).

    Returns:
        ``{"render_s": GL thread busy seconds, "frames": n, "kept": {index: (H, W, 3) RGB}}``.
    """
    return RenderPass(clip, track, animation, rig, folder, options, keep_frames).run(progress)

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


def render_stage(clip: str | os.PathLike, track, animation, rig: FaceRig, folder: str | os.PathLike,
                 options: RunOptions, progress: bool = True, keep_frames=()) -> dict:
    """Pass 3: avatar.mp4 and compare.mp4 into ``folder``, stages overlapped.

    One draw per frame gives both the character and its wrinkle-influence view (a second
    colour attachment); the GL thread only draws and reads back, while worker threads
    decode the source again, compose compare.mp4 frames and run the two H.264 encoders.

    Args:
        keep_frames: indices of frames to hand back as images (report.html's poster
            frames): compare.mp4's frames, or avatar.mp4's without ``options.compare``.
    Returns:
        ``{"render_s": GL thread busy seconds, "frames": n, "kept": {index: (H, W, 3) RGB}}``.
    """
    folder = Path(folder)
    n = animation.n_frames
    size = int(options.size)
    fps = float(track.fps)
    render_opts = run_render_options(options)
    poses = avatar_head_poses(rig, animation.head_pose, render_opts.fov_y_degrees).astype(np.float32)
    turns = avatar_head_rotations(rig, animation.head_pose)
    fitter = SourceFitter(track.width, track.height, size)
    q = max(2, int(options.queue_frames))
    threads = encoder_threads(software_gl())
    keep = {int(i) for i in keep_frames}
    kept: dict[int, np.ndarray] = {}
    # The source's frame times (a variable-rate clip keeps them) and its audio.
    times = np.asarray(track.times[:n], np.float64)
    audio_from = clip if options.audio else None

    def encode_avatar(frames) -> None:
        with VideoWriter(folder / "avatar.mp4", fps, (size, size), crf=options.crf, preset=options.preset,
                         threads=threads, times=times, audio_from=audio_from) as out:
            for frame in frames:
                out.write(frame)

    def decode_source(sink) -> None:
        for _, rgb in iter_frames(clip, max_frames=n):
            sink.put(rgb)
        sink.close()

    def encode_compare(panels, sources) -> None:
        src = iter(sources)
        with VideoWriter(folder / "compare.mp4", fps, (3 * size, size), crf=options.crf,
                         preset=options.preset, threads=threads, times=times, audio_from=audio_from) as out:
            for i, (avatar, heat) in enumerate(panels):
                frame = compare_frame(fitter, next(src, None), track.landmarks_px[i], bool(track.presence[i]),
                                      avatar, heat)
                out.write(frame)
                if i in keep:
                    kept[i] = frame
            for _ in src:  # drain, so the decoder is never left blocked
                pass

    busy = 0.0
    with StageGroup() as group, contextlib.ExitStack() as stack:
        avatar_q = group.channel(q)
        group.spawn("encode-avatar", encode_avatar, avatar_q)
        if options.compare:
            source_q, panel_q = group.channel(q), group.channel(q)
            group.spawn("decode", decode_source, source_q)
            group.spawn("encode-compare", encode_compare, panel_q, source_q)
        renderer = stack.enter_context(Renderer.create_from_options(rig, render_opts))
        bar = stack.enter_context(tqdm(total=n, disable=not progress, unit="frame", desc="rendering", leave=False))
        for i in range(n):
            raise_if_interrupted()
            t0 = time.perf_counter()
            state = FrameState(
                bone_positions=animation.bone_positions[i], blend_weights=animation.blend_weights[i],
                head_pose=poses[i], influences=animation.influences[i], zone_weights=animation.zone_weights[i],
                head_rotation=None if turns is None else turns[i],
                eye_rotation=None if animation.eye_rotation is None else animation.eye_rotation[i],
            )
            if options.compare:
                image, heat = renderer.render_with_influence(state)
            else:
                image = renderer.render(state)
            busy += time.perf_counter() - t0
            if i in keep and not options.compare:
                kept[i] = image.copy()
            avatar_q.put(image)
            if options.compare:
                panel_q.put((image, heat))
            bar.update(1)
        avatar_q.close()
        if options.compare:
            panel_q.close()
    return {"render_s": busy, "frames": n, "kept": kept}

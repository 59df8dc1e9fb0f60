"""Render throughput: ``python -m capture2face.eval.render_speed [--size 512] [--frames 60]
[--rounds 5] [--wrinkles off auto] [--samples 4] [--fxaa]``.

Frames sweep rest -> stretch -> rest -> compress with a slowly turning head, so every
frame has new uniforms (and, for ``dynamic``, new per-vertex weights). Timing covers
``Renderer.render`` including the read-back of the image; setup and one warm-up frame are
excluded. The drivers are timed interleaved (``--rounds`` rounds, each rendering the same
frames with every driver), and the median round is reported, so load from other
processes hits every driver alike.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from capture2face.camera import framing_pose
from capture2face.render.renderer import (
    WRINKLE_DRIVERS,
    FrameState,
    Renderer,
    RenderOptions,
)
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig


def sweep_states(rig: FaceRig, frames: int, fov_y_degrees: float = 30.0) -> list[FrameState]:
    """``frames`` states going through rest and every reference pose."""
    t = np.linspace(0.0, 1.0, frames, endpoint=False)
    n_poses = max(len(rig.pose_names), 1)
    phase = t * n_poses
    k = np.minimum(phase.astype(int), n_poses - 1)
    amount = np.sin(np.pi * (phase - k))  # 0 -> 1 -> 0 through each pose
    states = []
    for i in range(frames):
        bones, weights = rig.bone_rest.astype(np.float64), np.zeros(rig.n_morphs)
        if len(rig.pose_names):
            bones = bones + amount[i] * (rig.pose_bones[k[i]] - rig.bone_rest)
            weights = amount[i] * rig.pose_morph_weights[k[i]]
        pose = framing_pose(rig, yaw=15.0 * np.sin(2 * np.pi * t[i]), pitch=5.0 * np.cos(2 * np.pi * t[i]),
                            fov_y_degrees=fov_y_degrees)
        states.append(FrameState(bones, weights, pose))
    return states


def interleaved_fps(rig: FaceRig, drivers: list[str], frames: int = 60, rounds: int = 5,
                    size: int | tuple[int, int] = 512, **options) -> dict[str, list[float]]:
    """Frames per second of each driver in each of ``rounds`` rounds; within a round every
    driver renders the same ``frames`` states, the starting driver rotating."""
    base = RenderOptions(size=size, **options)
    states = sweep_states(rig, frames, base.fov_y_degrees)
    renderers = {}
    fps: dict[str, list[float]] = {d: [] for d in drivers}
    try:
        for d in drivers:
            renderers[d] = Renderer.create_from_options(rig, RenderOptions(size=size, wrinkles=d, **options))
            renderers[d].render(states[0])
        for k in range(rounds):
            for j in range(len(drivers)):
                d = drivers[(j + k) % len(drivers)]
                start = time.perf_counter()
                for state in states:
                    renderers[d].render(state)
                fps[d].append(frames / (time.perf_counter() - start))
    finally:
        for r in renderers.values():
            r.close()
    return fps


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--fxaa", action="store_true")
    parser.add_argument("--wrinkles", nargs="+", default=["off", "auto"], choices=WRINKLE_DRIVERS)
    parser.add_argument("--rig", help="a .rig.npz (default: the default avatar)")
    args = parser.parse_args(argv)
    rig = FaceRig.load(args.rig) if args.rig else default_avatar()
    drivers = list(dict.fromkeys(args.wrinkles))
    fps = interleaved_fps(rig, drivers, args.frames, args.rounds, args.size, samples=args.samples, fxaa=args.fxaa)
    for d in drivers:
        median = float(np.median(fps[d]))
        ratio = float(np.median(np.array(fps[d]) / np.array(fps[drivers[0]])))
        print(f"{d:8s} {args.size}x{args.size}: {median:6.1f} fps ({1000 / median:.1f} ms/frame), "
              f"{ratio:.2f} x {drivers[0]}; rounds {' '.join(f'{v:.1f}' for v in fps[d])}")


if __name__ == "__main__":
    main()

"""What ``run`` makes of a clip: :class:`RunOptions`, and the options of its stages."""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from capture2face.errors import CaptureError
from capture2face.render import RenderOptions
from capture2face.render.context import software_gl
from capture2face.render.renderer import WRINKLE_DRIVERS
from capture2face.rig.face_rig import FaceRig
from capture2face.tracking import TrackOptions

MIN_SIZE = 64
MAX_SIZE = 4096  # 4096^2 renders at ~0.1 fps on a software GL; 8K textures break drivers
OUTPUT_FILES = ("avatar.mp4", "compare.mp4", "track.npz", "animation.npz", "animation.glb",
                "livelink.csv", "report.html", "report.json")


def check_size(size: Any) -> None:
    """The render size: an even number of pixels in MIN_SIZE..MAX_SIZE."""
    if isinstance(size, bool) or not isinstance(size, int) and not hasattr(size, "__index__"):
        raise CaptureError(f"--size must be an even number of pixels from {MIN_SIZE} to {MAX_SIZE} (got {size!r})")
    size = int(size)
    if not MIN_SIZE <= size <= MAX_SIZE or size % 2:
        raise CaptureError(f"--size must be an even number of pixels from {MIN_SIZE} to {MAX_SIZE} (got {size})")


@dataclass
class RunOptions:
    """What ``run`` makes of a clip.

    Attributes:
        character: None (the default avatar), a built-in name ("default", "wide"), a
            FaceRig .npz (``FaceRig.save``), a .glb / .gltf (ARKit-named morphs are driven
            with no mapping; a mapping JSON beside it, ``<name>.json``, for face bones or
            other morph names), or a :class:`FaceRig`.
        wrinkles: wrinkle driver: auto (Dutreve bone masks), zones, dynamic, off.
        size: rendered frame size in pixels (square, even).
        neutral_frame: index of the neutral frame (None: each region's rest found in the clip).
        neutral_image, neutral_clip: instead, a photo or a short take of the actor at rest.
        face_model: MediaPipe ``face_landmarker.task`` (None: the default lookup).
        compare: also write compare.mp4.
        samples: MSAA samples of the renders; None: 4 on a GPU, and on a software GL
            (llvmpipe) 1 sample + an FXAA pass, whose edges look alike at ~55% of the cost.
        crf: H.264 quality of the videos (lower = better, larger).
        preset: x264 preset of the videos ("veryfast" encodes ~3x faster than "medium"
            at about the same size for rendered faces).
        queue_frames: frames buffered between overlapped stages.
        allow_truncated: process the frames before the damage of a truncated or
            corrupt clip (with a warning) instead of failing.
        audio: copy the clip's audio (if any) into avatar.mp4 and compare.mp4.
        faces: with several faces in view, the one that starts the track: "largest" or
            "center" (nearest the image centre); the one continuing it is followed.
        face: instead, the face with this index (0-based, left to right) in the first
            frame where more than ``face`` faces are seen, then followed.
        track_workers: MediaPipe landmarkers tracking segments of the clip at once, each
            in its own process (:mod:`capture2face.tracking.segments`); None: one per free
            core; 1: one. ``batch`` runs each clip with one when it runs clips in parallel.
    """

    character: Any = None
    wrinkles: str = "auto"
    size: int = 512
    neutral_frame: int | None = None
    neutral_image: str | os.PathLike | None = None
    neutral_clip: str | os.PathLike | None = None
    face_model: str | os.PathLike | None = None
    compare: bool = True
    samples: int | None = None
    crf: int = 20
    preset: str = "veryfast"
    queue_frames: int = 8
    allow_truncated: bool = False
    audio: bool = True
    faces: str = "largest"
    face: int | None = None
    track_workers: int | None = None

    def validate(self) -> None:
        if self.wrinkles not in WRINKLE_DRIVERS:
            raise CaptureError(f"unknown wrinkle driver '{self.wrinkles}'; choose one of {', '.join(WRINKLE_DRIVERS)}")

        check_size(self.size)  # even, 64..4096
        self.track_options().validate()  # faces, face, track_workers, neutral_frame

    def track_options(self):
        """The :class:`~capture2face.tracking.TrackOptions` of ``run``'s tracking."""
        return TrackOptions(face_model=self.face_model, neutral_frame=self.neutral_frame,
                            neutral_image=self.neutral_image, neutral_clip=self.neutral_clip, faces=self.faces,
                            face=self.face, workers=self.track_workers)


def run_render_options(options: RunOptions):
    """The :class:`~capture2face.render.RenderOptions` of ``run``'s character view (with
    ``compare``, its influence view comes out of the same draw)."""
    samples, fxaa = options.samples, False
    if samples is None:
        fxaa = software_gl()
        samples = 1 if fxaa else 4
    return RenderOptions(size=int(options.size), wrinkles=options.wrinkles, samples=int(samples), fxaa=fxaa,
                         influence_output=bool(options.compare))


def options_json(options: RunOptions) -> dict:
    out = {}
    for f in fields(options):
        v = getattr(options, f.name)
        if isinstance(v, FaceRig):
            v = v.name
        elif isinstance(v, os.PathLike):
            v = os.fspath(v)
        out[f.name] = v
    return out



def input_files(clip: str | os.PathLike, options: RunOptions) -> dict[str, str | None]:
    """The files a run's result depends on, by role: ``clip``, a neutral take, and for a character file
    ``character`` and (.glb / .gltf) ``mapping``, the JSON beside it, which need not exist.
    A built-in avatar or a FaceRig object has none."""
    files: dict[str, str | None] = {"clip": os.fspath(clip)}
    for role in ("neutral_image", "neutral_clip"):
        if getattr(options, role) is not None:
            files[role] = os.fspath(getattr(options, role))
    character = options.character
    if isinstance(character, (str, os.PathLike)) and Path(character).is_file():
        files["character"] = os.fspath(character)
        if Path(character).suffix.lower() in (".glb", ".gltf"):
            files["mapping"] = os.fspath(Path(character).with_suffix(".json"))
    return files

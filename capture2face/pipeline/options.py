"""What ``run`` makes of a clip: :class:`RunOptions`, and the options of its stages."""

from __future__ import annotations

import os
import warnings
from dataclasses import KW_ONLY, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

from capture2face.character.prepared import referenced_files
from capture2face.errors import CaptureError
from capture2face.gltf.container import CHARACTER_SUFFIXES
from capture2face.render import RenderOptions
from capture2face.render.context import software_gl
from capture2face.retarget import RetargetOptions
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.moved_options import get_path, keeps_moved_names
from capture2face.tracking import TrackOptions

MIN_SIZE = 64
MAX_SIZE = 4096  # 4096^2 renders at ~0.1 fps on a software GL; 8K textures break drivers
OUTPUT_FILES = ("avatar.mp4", "compare.mp4", "track.npz", "animation.npz", "animation.glb",
                "livelink.csv", "report.html", "report.json", "calibration.json")
#: Written only by a run given a calibration (``--calibration``): what it learned or loaded.
CALIBRATION_FILE = "calibration.json"


def check_size(size: Any) -> None:
    """The render size: an even number of pixels in MIN_SIZE..MAX_SIZE."""
    if isinstance(size, bool) or not isinstance(size, int) and not hasattr(size, "__index__"):
        raise CaptureError(f"--size must be an even number of pixels from {MIN_SIZE} to {MAX_SIZE} (got {size!r})")
    size = int(size)
    if not MIN_SIZE <= size <= MAX_SIZE or size % 2:
        raise CaptureError(f"--size must be an even number of pixels from {MIN_SIZE} to {MAX_SIZE} (got {size})")


#: RunOptions' keywords of before it composed its stages' options, and where they went.
MOVED_TO_STAGES = {
    "wrinkles": ("render", "wrinkles"),
    "size": ("render", "size"),
    "neutral_frame": ("track", "neutral_frame"),
    "neutral_image": ("track", "neutral_image"),
    "neutral_clip": ("track", "neutral_clip"),
    "face_model": ("track", "landmarker", "face_model"),
    "faces": ("track", "landmarker", "faces"),
    "face": ("track", "landmarker", "face"),
    "track_workers": ("track", "workers"),
}


@keeps_moved_names(MOVED_TO_STAGES)
@dataclass
class RunOptions:
    """What ``run`` makes of a clip: its stages' options, and run's own.

    The flat keywords of before (``RunOptions(size=512, wrinkles="auto")``) still work, with a
    ``DeprecationWarning`` naming their place (``RunOptions(render=RenderOptions(size=512))``).

    Attributes:
        character: None (the default avatar), a built-in name ("default", "wide"), a
            FaceRig .npz (``FaceRig.save``), a .glb / .gltf (ARKit-named morphs are driven
            with no mapping; a mapping JSON beside it, ``<name>.json``, for face bones or
            other morph names), or a :class:`FaceRig`.
        track: how the clip is tracked (:class:`~capture2face.tracking.TrackOptions`): the
            rest (``neutral_frame``, ``neutral_image``, ``neutral_clip``), which face
            (``landmarker.faces``, ``landmarker.face``), the face model
            (``landmarker.face_model``), the segment workers (``workers``: None, one per
            free core; ``batch`` runs each clip with one when it runs clips in parallel).
        render: how the character is drawn (:class:`~capture2face.render.RenderOptions`):
            ``size`` (square, even, 64..4096), ``wrinkles`` (auto, zones, dynamic, off).
            Its ``samples``, ``fxaa`` and ``influence_output`` are run's to set, from
            ``samples`` and ``compare`` below.
        retarget: how the track drives the character
            (:class:`~capture2face.retarget.RetargetOptions`).
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
    """

    character: Any = None
    _: KW_ONLY
    track: TrackOptions = field(default_factory=TrackOptions)
    render: RenderOptions = field(default_factory=RenderOptions)
    retarget: RetargetOptions = field(default_factory=RetargetOptions)
    compare: bool = True
    samples: int | None = None
    crf: int = 20
    preset: str = "veryfast"
    queue_frames: int = 8
    allow_truncated: bool = False
    audio: bool = True

    def validate(self) -> None:
        """Each stage's options (one line ``CaptureError`` each, named after the flags)
        and run's bound on the render size."""
        self.render.validate()  # wrinkles
        check_size(self.render.size)  # even, 64..4096
        self.track.validate()  # faces, face, workers, neutral_frame

    def track_options(self) -> TrackOptions:
        """Deprecated: :attr:`track`."""
        warnings.warn("RunOptions.track_options() is deprecated; use RunOptions.track", DeprecationWarning,
                      stacklevel=2)
        return self.track


def run_render_options(options: RunOptions) -> RenderOptions:
    """The :class:`~capture2face.render.RenderOptions` of ``run``'s character view: its
    ``render`` with the samples resolved (and FXAA on a software GL) and, with ``compare``,
    its influence view out of the same draw."""
    samples, fxaa = options.samples, False
    if samples is None:
        fxaa = software_gl()
        samples = 1 if fxaa else 4
    return replace(options.render, size=int(options.render.size), samples=int(samples), fxaa=fxaa,
                   influence_output=bool(options.compare))


#: report.json's "options" (and batch fingerprints): run's flat options of before, in this
#: order, each read from its place now; resumed batches compare them.
_JSON_FIELDS = ("character", "wrinkles", "size", "neutral_frame", "neutral_image", "neutral_clip", "face_model",
                "compare", "samples", "crf", "preset", "queue_frames", "allow_truncated", "audio", "faces", "face",
                "track_workers")
#: The options that name a file: stored by absolute path.
_FILE_FIELDS = ("character", "neutral_image", "neutral_clip", "face_model", "calibration")
#: Where each flat name of report.json's "options" lives (``calibration``: stored only when given).
_JSON_PATHS = {**MOVED_TO_STAGES, "calibration": ("track", "calibration")}
#: What run sets in its RenderOptions itself (not the user's to change).
_RUN_SETS = {"render": {"samples", "fxaa", "influence_output"}}


def options_json(options: RunOptions) -> dict:
    """``options`` as report.json stores them: the flat names of :data:`_JSON_FIELDS`, then
    ``track``, ``render`` and ``retarget`` each with the settings that differ from their
    defaults (only those not already among the flat names; none by default)."""
    out = {}
    for name in _JSON_FIELDS + (("calibration",) if options.track.calibration is not None else ()):
        v = get_path(options, _JSON_PATHS.get(name, (name,)))
        if name == "calibration":
            v = calibration_file(v)
        if isinstance(v, FaceRig):
            v = v.name
        elif isinstance(v, os.PathLike):
            v = os.fspath(v)
        if name in _FILE_FIELDS and isinstance(v, str) and Path(v).exists():
            v = os.path.abspath(v)  # a file: found again from any folder (eval fidelity RUN_DIR, batch --resume)
        out[name] = v
    for part in ("track", "render", "retarget"):
        skip = {path[1:] for path in _JSON_PATHS.values() if path[0] == part}
        skip |= {(name,) for name in _RUN_SETS.get(part, ())}
        changed = _changed_settings(getattr(options, part), skip)
        if changed:
            out[part] = changed
    return out


def _changed_settings(options: Any, skip: set[tuple[str, ...]], prefix: tuple[str, ...] = ()) -> dict:
    """The fields of a (nested) options dataclass that differ from its defaults, but ``skip``."""
    default = type(options)()
    out = {}
    for f in fields(options):
        value, path = getattr(options, f.name), prefix + (f.name,)
        if path in skip:
            continue
        if is_dataclass(value):
            value = _changed_settings(value, skip, path)
            if value:
                out[f.name] = value
        elif value != getattr(default, f.name):
            out[f.name] = os.fspath(value) if isinstance(value, os.PathLike) else value
    return out


def calibration_file(calibration: Any) -> str | None:
    """The file a calibration option names: its path, or for an ``ActorCalibration`` (a
    batch's take, learned once) the take it was learned from; None for none."""
    if calibration is None:
        return None
    if isinstance(calibration, (str, os.PathLike)):
        return os.fspath(calibration)
    return str(getattr(calibration, "source", "")) or None


def input_files(clip: str | os.PathLike, options: RunOptions) -> dict[str, str | None]:
    """The files a run's result depends on, by role: ``clip``, a neutral take or calibration, and for a character file
    ``character`` and (.glb / .gltf) ``mapping``, the JSON beside it, which need not exist, and
    the files they reference (``character file:<name>``: a .gltf's buffers and images;
    ``mapping file:<name>``: wrinkle maps, zone masks). A built-in avatar or a FaceRig object
    has none."""
    files: dict[str, str | None] = {"clip": os.fspath(clip)}
    for role in ("neutral_image", "neutral_clip"):
        if getattr(options.track, role) is not None:
            files[role] = os.fspath(getattr(options.track, role))
    calibration = calibration_file(options.track.calibration)
    if calibration is not None:
        files["calibration"] = calibration
    character = options.character
    if isinstance(character, (str, os.PathLike)) and Path(character).is_file():
        files["character"] = os.fspath(character)
        if Path(character).suffix.lower() in CHARACTER_SUFFIXES:
            mapping = Path(character).with_suffix(".json")
            files["mapping"] = os.fspath(mapping)
            # A .gltf's .bin and textures, the maps its mapping names: by role "<owner> file:<path>".
            owners = ([("character", Path(character))] if Path(character).suffix.lower() == ".gltf" else []) \
                + [("mapping", mapping)]
            for owner, path in owners:
                for ref in referenced_files(path):
                    name = Path(os.path.relpath(ref, path.parent)).as_posix()
                    files.setdefault(f"{owner} file:{name}", os.fspath(ref))
    return files

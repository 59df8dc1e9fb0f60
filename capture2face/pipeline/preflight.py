"""Checks that run before a clip is tracked: everything that can fail without the clip's
landmarks fails in seconds, not after minutes of tracking.

:func:`preflight` is what :func:`capture2face.pipeline.run` calls first (and
:func:`capture2face.batch.run_batch` once per batch for what all clips share): the options
and their limits, the clip (it decodes; the neutral frame lies inside it), the neutral
image or clip (it decodes), the calibration (an actor.json loads, a take decodes), the
face model, the character (it loads and the retargeting can drive it), and the OpenGL
context.
"""

from __future__ import annotations

import os
from typing import Any

from capture2face.character.load import load_character
from capture2face.errors import CaptureError
from capture2face.io.video_input import open_video
from capture2face.models.face_model import find_face_model
from capture2face.pipeline.calibration import check_calibration
from capture2face.render.context import gl_context
from capture2face.rig.arkit_names import drive_mode
from capture2face.tracking.calibration import neutral_take

# A frame count estimated from the duration (no count in the container) may be low by
# a few percent on variable-frame-rate clips: only a neutral frame clearly past the end is
# refused here; the tracker checks against the frames it decoded.
_ESTIMATE_SLACK = 1.25


def check_neutral_frame(neutral_frame: int | None, info) -> None:
    """``--neutral-frame`` against the clip's frame count (a
    :class:`~capture2face.io.video_input.VideoInfo`)."""
    if neutral_frame is None:
        return
    n = int(info.n_frames)
    limit = n if getattr(info, "n_frames_exact", True) else int(n * _ESTIMATE_SLACK) + 1
    if not 0 <= int(neutral_frame) < limit:
        about = "" if getattr(info, "n_frames_exact", True) else "about "
        raise CaptureError(f"--neutral-frame {neutral_frame} is outside the clip "
                           f"({info.path} has {about}{n} frames: 0..{n - 1})")


def check_neutral_take(track_options) -> None:
    """``--neutral-image`` / ``--neutral-clip`` decodes (an image too large for FFmpeg, a
    damaged file), as the clip does: it is tracked first, before the clip."""
    take = neutral_take(track_options)
    if take is None:
        return
    kind, path = take
    try:
        open_video(path)
    except CaptureError as exc:
        raise CaptureError(f"--neutral-{kind}: {exc}") from None


def check_character(character: Any = None, progress: bool = False):
    """Load the character and check that the retargeting can drive it (``progress``: a
    progress bar while a built-in avatar is first built).

    Returns:
        The :class:`~capture2face.rig.face_rig.FaceRig`.
    Raises:
        CaptureError: missing or corrupt file (an unsupported required glTF extension
            named), or a character with neither face bones nor ARKit-named morphs.
    """
    rig = load_character(character, progress)
    drive_mode(rig)  # raises CaptureError for an undrivable character, saying what is missing
    return rig


def check_gl() -> None:
    """The headless OpenGL context can be created (one line naming the missing package
    otherwise; see :mod:`capture2face.render.context`)."""
    gl_context()


def check_shared(options, progress: bool = False) -> Any:
    """What every clip of a run or a batch shares: the options, the face model and the
    character (the GL context is checked apart: batch workers, e.g. Ray's, may be elsewhere).

    Returns:
        The character's FaceRig.
    """
    options.validate()
    find_face_model(options.track.landmarker.face_model)
    return check_character(options.character, progress)


def preflight(clip: str | os.PathLike, options, progress: bool = False) -> tuple[Any, Any]:
    """Every check :func:`capture2face.pipeline.run` can make before tracking ``clip``
    (``progress``: a progress bar while a built-in avatar is first built).

    Returns:
        ``(VideoInfo, FaceRig)``.
    Raises:
        CaptureError: the first problem found, as one line.
    """
    options.validate()
    info = open_video(clip)
    check_neutral_frame(options.track.neutral_frame, info)
    check_neutral_take(options.track)
    check_calibration(options.track)
    rig = check_shared(options, progress)
    check_gl()
    return info, rig

"""``--calibration``: the actor's calibration (:mod:`capture2face.calibration`) a clip is
run with: loaded from an ``actor.json``, or learned from a range-of-motion take tracked
as the clip is; checked before tracking, and its report.json section."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from capture2face.calibration import ActorCalibration
from capture2face.errors import CaptureError
from capture2face.io.video_input import open_video
from capture2face.retarget.arkit import calibrate_take
from capture2face.tracking import TrackOptions, track_clip

CALIBRATION_SUFFIX = ".json"  # an actor.json; any other file is a take to learn from


def is_calibration_file(path: str | os.PathLike) -> bool:
    return Path(path).suffix.lower() == CALIBRATION_SUFFIX


def check_calibration(options: TrackOptions) -> None:
    """``--calibration`` before anything is tracked: an actor.json loads (one line naming
    what is wrong), a take decodes."""
    value = options.calibration
    if not isinstance(value, (str, os.PathLike)):
        return
    if is_calibration_file(value):
        ActorCalibration.load(value)
        return
    try:
        open_video(value)
    except CaptureError as exc:
        raise CaptureError(f"--calibration: {exc}") from None


def take_options(options: TrackOptions) -> TrackOptions:
    """How a range-of-motion take is tracked: as the clip (face model, face choice,
    workers, filters), without the clip's own rest or calibration."""
    return dataclasses.replace(options, neutral_frame=None, neutral_image=None, neutral_clip=None,
                               calibration=None, max_frames=None)


def learn_calibration(take: str | os.PathLike, options: TrackOptions | None = None,
                      progress: bool = True) -> ActorCalibration:
    """Track the range-of-motion ``take`` (``options``: :func:`take_options` of them) and
    learn the actor's calibration from it (never fails for a badly performed take: its
    ``warnings`` say what was missing).

    Raises:
        CaptureError: the take cannot be read or shows no face (named after --calibration).
    """
    try:
        track = track_clip(take, take_options(options or TrackOptions()), progress=progress)
    except CaptureError as exc:
        raise CaptureError(f"--calibration: {exc}") from None
    if not track.tracked_frames:
        raise CaptureError(f"--calibration {os.fspath(take)}: no face in the take")
    return calibrate_take(track)


def resolve_calibration(options: TrackOptions, progress: bool = True) -> ActorCalibration | None:
    """``options.calibration`` as an :class:`ActorCalibration`: loaded (an actor.json),
    learned (a take, tracked with ``options``), or already one; None without."""
    value = options.calibration
    if value is None or isinstance(value, ActorCalibration):
        return value
    if is_calibration_file(value):
        return ActorCalibration.load(value)
    return learn_calibration(value, options, progress)


def calibration_summary(calibration: ActorCalibration) -> str:
    """``steps found 18/20, 12 curves calibrated`` (several takes: ``3 takes, steps found
    18/20, 20/20, 17/20, ...``): a calibration at a glance."""
    takes = calibration.takes
    found = ", ".join(f"{sum(1 for s in t.steps if s.found)}/{len(t.steps)}" for t in takes)
    return (f"{len(takes)} takes, " if len(takes) > 1 else "") + \
        f"steps found {found}, {len(calibration.curves)} curves calibrated"


def calibration_report(calibration: ActorCalibration) -> dict:
    """report.json's ``calibration`` section: the take, each step as found (frames, the hold,
    how it matched, the tracker's reading before and after), the curves and the warnings."""
    data = calibration.to_json()
    keys = ("source", "steps", "curves", "warnings")
    out = {key: data[key] for key in keys}
    if calibration.more_takes:  # each further take as the first
        out["more_takes"] = [{key: t[key] for key in keys} for t in data["more_takes"]]
    return out

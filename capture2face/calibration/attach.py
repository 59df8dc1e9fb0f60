"""A clip's track carrying its actor's calibration (as its JSON text, saved with the track),
so that every stage after tracking (the ARKit curves, the character solve, the exports)
reads the same actor's calibration, from a track file too.

The track keeps its own rest: a take's rest laid onto a real clip made its figures worse
(docs/calibration.md), while the calibration reads its own curves against the take's rest
(:func:`~capture2face.calibration.learn.calibrated_curves`)."""

from __future__ import annotations

import dataclasses
import functools
import json

from capture2face.calibration.model import ActorCalibration


def attach(track, calibration: ActorCalibration):
    """``track`` with the calibration in its ``calibration`` field (its rest its own)."""
    return dataclasses.replace(track, calibration=json.dumps(calibration.to_json()))


@functools.lru_cache(maxsize=4)
def _parsed(text: str) -> ActorCalibration:
    return ActorCalibration.from_json(json.loads(text), "the track's calibration")


def track_calibration(track) -> ActorCalibration | None:
    """The calibration a track carries, or None."""
    text = getattr(track, "calibration", "") or ""
    return _parsed(text) if text else None

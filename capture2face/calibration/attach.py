"""A clip's track carrying its actor's calibration (as its JSON text, saved with the track),
so that every stage after tracking (the ARKit curves, the character solve, the wrinkles'
rest, the exports) reads the same actor's calibration, from a track file too; the track
rests on the take's neutral, laid onto its head coordinates."""

from __future__ import annotations

import dataclasses
import functools
import json

from capture2face.calibration.learn import calibration_rest
from capture2face.calibration.model import ActorCalibration
from capture2face.tracking.rest import rest_fields


def attach(track, calibration: ActorCalibration):
    """``track`` resting on the calibration's rest (aligned to its head coordinates), with
    the calibration in its ``calibration`` field."""
    rest = calibration_rest(calibration, track)
    return dataclasses.replace(track, **rest_fields(rest), calibration=json.dumps(calibration.to_json()))


@functools.lru_cache(maxsize=4)
def _parsed(text: str) -> ActorCalibration:
    return ActorCalibration.from_json(json.loads(text), "the track's calibration")


def track_calibration(track) -> ActorCalibration | None:
    """The calibration a track carries, or None."""
    text = getattr(track, "calibration", "") or ""
    return _parsed(text) if text else None

"""Calibration from outside the clip, as Live Link Face's calibration and MetaHuman
Animator's neutral pose do: the actor's rest taken from a photo (``--neutral-image``) or
a short rest take (``--neutral-clip``) of the same actor, tracked as the clip is, then
laid onto the clip's head coordinates (:func:`~capture2face.tracking.rest.aligned_rest`:
a photo's camera and distance differ from the clip's)."""

from __future__ import annotations

import dataclasses
import os

from capture2face.errors import CaptureError
from capture2face.tracking.options import TrackOptions
from capture2face.tracking.rest import ActorRest, actor_rest, aligned_rest, frame_rest, rest_fields
from capture2face.tracking.track import Track


def neutral_take(options: TrackOptions) -> tuple[str, str] | None:
    """(kind, path) of the options' rest from outside the clip ("image" or "clip"), or None."""
    if options.neutral_image is not None:
        return "image", os.fspath(options.neutral_image)
    if options.neutral_clip is not None:
        return "clip", os.fspath(options.neutral_clip)
    return None


def take_rest(kind: str, path: str, options: TrackOptions, track_fn) -> ActorRest:
    """The rest of a neutral image (its one frame) or clip (each region's calmest frames),
    tracked by ``track_fn(path, options)`` with the clip's own tracking options.

    Raises:
        CaptureError: the take cannot be read or shows no face (named after its flag).
    """
    plain = dataclasses.replace(options, neutral_frame=None, neutral_image=None, neutral_clip=None,
                                workers=1, max_frames=None)
    try:
        take = track_fn(path, plain)
    except CaptureError as exc:
        raise CaptureError(f"--neutral-{kind}: {exc}") from None
    if kind == "image":
        valid = take.presence.nonzero()[0]
        first = int(valid[0]) if len(valid) else 0
        return frame_rest(take.landmarks_head, take.blendshapes, list(take.blendshape_names), first, f"image {path}")
    return dataclasses.replace(actor_rest(take), source=f"clip {path}")


def calibrated(track: Track, rest: ActorRest) -> Track:
    """``track`` resting on ``rest`` from outside the clip, aligned onto its head coordinates."""
    moved = aligned_rest(rest, track.landmarks_head, track.presence)
    return dataclasses.replace(track, **rest_fields(moved))

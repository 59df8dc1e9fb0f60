"""``capture2face eval fidelity``'s figures from cached tracks (docs/accuracy.md's tables).

    python tools/fidelity_on_tracks.py [CLIP ...] [--character FILE] [--cache DIR] [--json PATH]
        [--calibration actor.json | --take first:SECONDS | --take rest]

The same figures, table and summary line as ``capture2face eval fidelity CLIP ...
[--character FILE]``, without tracking the clips each time: each clip's track comes from
tools/track_clips.py's cache (tracked there first when missing), then goes through what
``eval fidelity`` does with it (``pipeline.retarget_stage``, ``measures.clip_fidelity``).
Clips default to ``../shared/clips/*.mp4``; ``--character`` takes what ``eval fidelity``
takes (a .glb or FaceRig .npz, or a built-in avatar's name; default: the default avatar).

With a calibration (docs/calibration.md) each track carries it first: ``--calibration``
an actor.json for every clip; ``--take first:S`` calibrates each clip on its own first S
seconds (a partial range-of-motion take, in-sample: the frames judged include the take's);
``--take rest`` on a take of the clip's calmest frames alone (those the whole face's rest
takes: a take holding only a neutral).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from track_clips import cached_track, character_arguments, chosen_clips, clip_arguments


def take_of(track, spec: str):
    """The frames of ``track`` a ``--take`` names, as a Track of their own."""
    import numpy as np

    from capture2face.tracking.rest import actor_rest

    if spec == "rest":
        frames = np.asarray(actor_rest(track).frames["face"], np.int64)  # the whole face at its calmest
    elif spec.startswith("first:"):
        frames = np.flatnonzero(np.asarray(track.times) < float(spec.split(":", 1)[1]))
    else:
        raise SystemExit(f"--take {spec}: expected first:SECONDS or rest")
    per_frame = ("times", "landmarks_px", "landmarks_depth", "landmarks_head", "presence", "interpolated", "held",
                 "blendshapes", "head_pose")
    cut = {name: np.asarray(getattr(track, name))[frames] for name in per_frame}
    return dataclasses.replace(track, **cut, neutral_frame=0, rest_face=None, rest_landmarks=None, rest_scores=None,
                               rest_frames=None, rest_source="", source=f"{track.source} ({spec})")


def fidelity_on_tracks(clips: list[Path], cache: Path, character=None, progress: bool = False,
                       calibration: Path | None = None, take: str | None = None) -> dict:
    """``{"clips": [figures per clip], "summary": line}``, as ``eval.fidelity.evaluate_fidelity``."""
    from capture2face.calibration import ActorCalibration
    from capture2face.calibration.attach import attach
    from capture2face.character.load import load_character
    from capture2face.eval.fidelity import summary_line
    from capture2face.measures import clip_fidelity
    from capture2face.pipeline import retarget_stage
    from capture2face.retarget.arkit import calibrate_take

    actor = ActorCalibration.load(calibration) if calibration else None
    results = []
    for clip in clips:
        rig = load_character(character)  # per clip, as eval fidelity loads it
        track = cached_track(clip, cache, progress=progress)
        if actor is not None or take:
            track = attach(track, actor if actor is not None else calibrate_take(take_of(track, take)))
        animation = retarget_stage(track, rig)
        results.append(clip_fidelity(track, animation, rig, clip.stem).figures())
    return {"clips": results, "summary": summary_line(results)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    clip_arguments(parser)
    character_arguments(parser, "write every figure as JSON (eval fidelity's)")
    parser.add_argument("--calibration", type=Path, default=None, help="an actor.json every track carries")
    parser.add_argument("--take", default=None, help="first:SECONDS or rest: calibrate each clip on those frames")
    args = parser.parse_args(argv)
    clips, cache = chosen_clips(args)
    from capture2face.eval.fidelity import table

    result = fidelity_on_tracks(clips, cache, args.character, progress=True, calibration=args.calibration,
                                take=args.take)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(table(result["clips"]))
    print(result["summary"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""``capture2face eval fidelity``'s figures from cached tracks (docs/accuracy.md's tables).

    python tools/fidelity_on_tracks.py [CLIP ...] [--character FILE] [--cache DIR] [--json PATH]

The same figures, table and summary line as ``capture2face eval fidelity CLIP ...
[--character FILE]``, without tracking the clips each time: each clip's track comes from
tools/track_clips.py's cache (tracked there first when missing), then goes through what
``eval fidelity`` does with it (``pipeline.retarget_stage``, ``measures.clip_fidelity``).
Clips default to ``../shared/clips/*.mp4``; ``--character`` takes what ``eval fidelity``
takes (a .glb or FaceRig .npz, or a built-in avatar's name; default: the default avatar).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from track_clips import cached_track, character_arguments, chosen_clips, clip_arguments


def fidelity_on_tracks(clips: list[Path], cache: Path, character=None, progress: bool = False) -> dict:
    """``{"clips": [figures per clip], "summary": line}``, as ``eval.fidelity.evaluate_fidelity``."""
    from capture2face.character.load import load_character
    from capture2face.eval.fidelity import summary_line
    from capture2face.measures import clip_fidelity
    from capture2face.pipeline import retarget_stage

    results = []
    for clip in clips:
        rig = load_character(character)  # per clip, as eval fidelity loads it
        track = cached_track(clip, cache, progress=progress)
        animation = retarget_stage(track, rig)
        results.append(clip_fidelity(track, animation, rig, clip.stem).figures())
    return {"clips": results, "summary": summary_line(results)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    clip_arguments(parser)
    character_arguments(parser, "write every figure as JSON (eval fidelity's)")
    args = parser.parse_args(argv)
    clips, cache = chosen_clips(args)
    from capture2face.eval.fidelity import table

    result = fidelity_on_tracks(clips, cache, args.character, progress=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(table(result["clips"]))
    print(result["summary"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Each morph's solved weight against the clip's ARKit curve of the same name (docs/characters.md's
per-morph tables): the 99th percentile of both over the clip.

    python tools/morph_ranges.py [CLIP ...] --character FILE [--cache DIR] [--morphs NAME ...] [--frames A:B]

Each clip's track comes from tools/track_clips.py's cache (tracked there first when missing),
then goes through ``pipeline.retarget_stage`` as in ``capture2face run``. A morph whose weight
sits far above its curve where the actor never makes that face (``browDown`` against a brow
raise) is the solve trading one morph against another. ``--frames A:B`` gives the mean of both
over frames A to B-1 instead (one expression: d18's grimace, 117:126).
"""

from __future__ import annotations

import argparse

import numpy as np
from track_clips import cached_track, chosen_clips, clip_arguments


def morph_ranges(track, animation, names: list[str] | None = None, frames: slice | None = None
                 ) -> list[tuple[str, float, float]]:
    """(ARKit name, curve p99, solved weight p99) for each of the character's ARKit-named morphs;
    with ``frames``, the means over those frames."""
    from capture2face.rig.arkit_names import canonical_arkit

    curves = dict(zip(animation.arkit_names, np.asarray(animation.arkit_weights).T, strict=True))
    rows = {}
    for m, morph in enumerate(animation.blend_names):
        name = canonical_arkit(morph)
        if name is None or name not in curves or (names and name not in names) or name in rows:
            continue
        weight = np.asarray(animation.blend_weights)[:, m]
        if frames is None:
            rows[name] = (float(np.percentile(curves[name], 99)), float(np.percentile(weight, 99)))
        else:
            rows[name] = (float(np.mean(curves[name][frames])), float(np.mean(weight[frames])))
    return [(n, c, w) for n, (c, w) in sorted(rows.items())]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    clip_arguments(parser)
    parser.add_argument("--character", required=True, help="a .glb / .vrm / .gltf with ARKit-named morphs")
    parser.add_argument("--morphs", nargs="*", default=None, metavar="NAME", help="only these ARKit names")
    parser.add_argument("--frames", default=None, metavar="A:B", help="means over frames A to B-1, not p99")
    args = parser.parse_args(argv)
    frames = None if args.frames is None else slice(*(int(v) for v in args.frames.split(":")))
    clips, cache = chosen_clips(args)

    from capture2face.character.load import load_character
    from capture2face.pipeline import retarget_stage

    rig = load_character(args.character)
    for clip in clips:
        track = cached_track(clip, cache)
        animation = retarget_stage(track, rig)
        what = "p99" if frames is None else f"mean {args.frames}"
        print(f"{clip.stem}: morph | curve {what} | weight {what}")
        for name, curve, weight in morph_ranges(track, animation, args.morphs, frames):
            print(f"  {name} | {curve:.2f} | {weight:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

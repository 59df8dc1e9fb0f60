"""Issue 21's wrinkle goals on real clips (docs/rest.md's goals table), from cached tracks.

    python tools/wrinkle_goals.py [CLIP ...] [--character FILE] [--cache DIR] [--json PATH]

The goals are stated against the tracker's scores, not the geometry ``eval fidelity``
judges (docs/accuracy.md):

* where browDown (both sides' scores, their maximum) stays below 0.1 throughout: the
  glabella's "compress" influence's 99th percentile below 0.15 (``eval fidelity``'s
  ``glabella_unfrowned`` check);
* where browDown (the mean of both sides) moves by 0.3 (max - min): glabella compress
  follows it, Pearson r >= 0.8;
* where browInnerUp moves by 0.3: the forehead's "stretch" influence follows it, r >= 0.8.

Each clip's track comes from tools/track_clips.py's cache (tracked first when missing) and
is retargeted as ``capture2face run`` and ``eval fidelity`` retarget it
(``pipeline.retarget_stage``); the influences and scores are those of the tracked frames
(``measures.clip_fidelity``). Clips default to ``../shared/clips/*.mp4``, the character to
the default avatar (``--character`` as ``eval fidelity``'s).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from track_clips import cached_track, character_arguments, chosen_clips, clip_arguments

NEVER_LOWER, AT_REST_P99 = 0.1, 0.15  # browDown's maximum; compress's 99th percentile goal
MOVES_BY, R_GOAL = 0.3, 0.8  # a score's range from which r is judged; the r goal
BROW_DOWN = ("browDownLeft", "browDownRight")


@dataclass
class Goal:
    """One judged goal of one clip: ``value`` (a p99 or an r) against ``goal``."""

    clip: str
    goal: str
    value: float
    met: bool


def clip_goals(name: str, scores: np.ndarray, score_names: list[str], wrinkles: np.ndarray) -> list[Goal]:
    """The goals judged on one clip.

    Args:
        scores: (T, S) the tracker's scores of the tracked frames, names in ``score_names``.
        wrinkles: (T, 2) forehead stretch and glabella compress (``ClipFidelity.wrinkles``).
    """
    from capture2face.maths.stats import pearson

    stretch, compress = wrinkles[:, 0], wrinkles[:, 1]
    down_sides = scores[:, [score_names.index(n) for n in BROW_DOWN]]
    down, inner_up = down_sides.mean(1), scores[:, score_names.index("browInnerUp")]
    goals = []
    if down_sides.max() < NEVER_LOWER:
        p99 = float(np.percentile(compress, 99))
        goals.append(Goal(name, "compress p99", p99, p99 < AT_REST_P99))
    if np.ptp(down) >= MOVES_BY:
        r = pearson(compress, down)
        goals.append(Goal(name, "compress ~ browDown r", r, r >= R_GOAL))
    if np.ptp(inner_up) >= MOVES_BY:
        r = pearson(stretch, inner_up)
        goals.append(Goal(name, "stretch ~ browInnerUp r", r, r >= R_GOAL))
    return goals


def wrinkle_goals(clips: list[Path], cache: Path, character=None, progress: bool = False) -> list[Goal]:
    """Every clip's judged goals, in clip order."""
    from capture2face.character.load import load_character
    from capture2face.measures import clip_fidelity
    from capture2face.pipeline import retarget_stage

    rig = load_character(character)
    goals = []
    for clip in clips:
        track = cached_track(clip, cache, progress=progress)
        fid = clip_fidelity(track, retarget_stage(track, rig), rig, clip.stem)
        if fid.wrinkles is None:
            raise SystemExit(f"{clip.stem}: the character has no forehead / glabella wrinkle regions")
        goals += clip_goals(fid.name, fid.scores, fid.score_names, fid.wrinkles)
    return goals


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    clip_arguments(parser)
    character_arguments(parser, "write the goals as JSON")
    args = parser.parse_args(argv)
    clips, cache = chosen_clips(args)
    goals = wrinkle_goals(clips, cache, args.character, progress=True)
    if args.json:
        args.json.write_text(json.dumps([asdict(g) for g in goals], indent=2) + "\n", encoding="utf-8")
    print("| clip | goal | value | met |\n|---|---|---|---|")
    for g in goals:
        print(f"| {g.clip} | {g.goal} | {g.value:.2f} | {'yes' if g.met else 'no'} |")
    print(f"met {sum(g.met for g in goals)}/{len(goals)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

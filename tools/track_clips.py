"""Track clips once into a cache folder, for the measurement tools beside this script.

    python tools/track_clips.py [CLIP ...] [--cache DIR] [--force]

Each clip is tracked the way ``capture2face run`` and ``capture2face eval fidelity`` track
it (``pipeline.track_stage`` with the default ``RunOptions``) and saved as
``DIR/<clip name>/track.npz``, beside a ``source.json`` naming the clip, its size and its
modification time; a clip whose cached track matches them is not tracked again. Clips
default to ``../shared/clips/*.mp4`` (relative to the repository), the cache to
``$CAPTURE2FACE_CACHE/tracks`` (default ``~/.cache/capture2face/tracks``).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CLIPS = REPO.parent / "shared" / "clips"


def default_cache() -> Path:
    """The track cache folder: ``$CAPTURE2FACE_CACHE/tracks`` (the project's disk cache)."""
    root = os.environ.get("CAPTURE2FACE_CACHE") or Path.home() / ".cache" / "capture2face"
    return Path(root) / "tracks"


def default_clips() -> list[Path]:
    """The shared real clips (``../shared/clips/*.mp4``), in name order."""
    return sorted(DEFAULT_CLIPS.glob("*.mp4"))


def _stamp(clip: Path) -> dict:
    stat = clip.stat()
    return {"clip": os.fspath(clip.resolve()), "bytes": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def cached_track(clip: str | os.PathLike, cache: str | os.PathLike, force: bool = False, progress: bool = False):
    """The clip's ``Track``: read from ``cache`` when tracked before from the same file,
    else tracked now (as ``eval fidelity`` tracks a clip) and written there."""
    from capture2face.pipeline import RunOptions, track_stage
    from capture2face.tracking.track import Track

    clip = Path(clip)
    folder = Path(cache) / clip.stem
    stamp = _stamp(clip)
    path, stamp_path = folder / "track.npz", folder / "source.json"
    if (not force and path.is_file() and stamp_path.is_file()
            and json.loads(stamp_path.read_text(encoding="utf-8")) == stamp):
        return Track.load(path)
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="capture2face-track-") as work:
        track = track_stage(clip, RunOptions(), progress=progress, workdir=work)
        track.save(path)
    stamp_path.write_text(json.dumps(stamp, indent=2) + "\n", encoding="utf-8")
    return Track.load(path)  # what later reads get, so the first run's figures equal theirs


def clip_arguments(parser: argparse.ArgumentParser) -> None:
    """The clip and cache arguments the measurement tools share."""
    parser.add_argument("clips", nargs="*", type=Path, metavar="CLIP",
                        help=f"clips to track (default: {DEFAULT_CLIPS.relative_to(REPO.parent)}/*.mp4 "
                             "beside the repository)")
    parser.add_argument("--cache", type=Path, default=None, metavar="DIR",
                        help="track cache folder (default: $CAPTURE2FACE_CACHE/tracks, "
                             "~/.cache/capture2face/tracks)")


def character_arguments(parser: argparse.ArgumentParser, json_help: str) -> None:
    """The measurement tools' ``--character`` (as eval fidelity's) and ``--json``."""
    parser.add_argument("--character", metavar="FILE", default=None,
                        help="character for the clips, as eval fidelity's --character (default avatar)")
    parser.add_argument("--json", type=Path, metavar="PATH", help=json_help)


def chosen_clips(args: argparse.Namespace) -> tuple[list[Path], Path]:
    """(clips, cache folder) from :func:`clip_arguments`' arguments; exits when there is no clip."""
    clips = list(args.clips) or default_clips()
    if not clips:
        raise SystemExit(f"no clips given and none in {DEFAULT_CLIPS}")
    missing = [c for c in clips if not c.is_file()]
    if missing:
        raise SystemExit(f"no such clip: {missing[0]}")
    return clips, args.cache or default_cache()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    clip_arguments(parser)
    parser.add_argument("--force", action="store_true", help="track again even where a cached track matches")
    args = parser.parse_args(argv)
    clips, cache = chosen_clips(args)
    for clip in clips:
        track = cached_track(clip, cache, force=args.force, progress=True)
        print(f"{clip.stem}: {track.n_frames} frames -> {cache / clip.stem / 'track.npz'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

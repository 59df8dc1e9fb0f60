"""``run``'s report: which outputs make a finished run, and the warnings it reports."""

from __future__ import annotations

import json
import os
from pathlib import Path

from capture2face.errors import CaptureError
from capture2face.pipeline.options import RunOptions
from capture2face.tracking.rest import actor_rest, rest_warnings


def outputs_complete(folder: str | os.PathLike) -> bool:
    """True when ``folder`` holds a finished run: report.json and every output it lists."""
    folder = Path(folder)
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    names = report.get("outputs") or []
    return bool(names) and all((folder / name).is_file() and (folder / name).stat().st_size > 0 for name in names)


def check_same_clip(final: str | os.PathLike, clip: dict | None) -> None:
    """Refuse to replace the outputs of another clip that has the same name
    (``day1/take.mp4`` and ``day2/take.mp4`` both go to ``OUT/take``).

    ``clip`` is this run's clip fingerprint (:func:`capture2face.io.fingerprint.fingerprint`);
    the one in ``final``'s report.json is compared: the same path, or the same content
    (a clip that was moved), may replace its outputs.

    Raises:
        CaptureError: ``final`` holds the outputs of a clip at another path with other content.
    """
    try:
        stored = json.loads((Path(final) / "report.json").read_text(encoding="utf-8"))
        old = stored["inputs"]["clip"]
        old_path = old["path"]
    except (OSError, ValueError, KeyError, TypeError):
        return  # no earlier run (or one that stored no fingerprint): nothing to tell apart
    if clip is None or old_path == clip["path"]:
        return
    if old.get("size") == clip["size"] and old.get("sha256") == clip["sha256"]:
        return
    raise CaptureError(f"{final} holds the outputs of another clip, {old_path}; to keep both, choose another "
                       "output folder (run: or another folder name, --name NAME); to replace them, delete "
                       f"{final} first")


def track_warnings(track, options: RunOptions | None = None) -> list[str]:
    out = []
    missing = track.n_frames - track.tracked_frames
    if missing:
        out.append(f"no face in {missing} of {track.n_frames} frames ({track.n_gaps} gaps); "
                   "short gaps are interpolated, longer ones hold the last pose")
    if track.n_long_gaps:
        out.append(f"{track.n_long_gaps} gaps longer than the interpolation limit hold the last pose")
    if track.n_faces_max > 1:
        chosen = options.track.landmarker if options is not None else None
        face, faces = (chosen.face, chosen.faces) if chosen is not None else (None, "largest")
        start = (f"face {face} from the left" if face is not None
                 else "the face nearest the centre" if faces == "center" else "the largest face")
        out.append(f"{track.n_faces_max} faces in view (the most seen at once); tracked: {start} at the start, "
                   "then the one continuing the track (choose with --face N or --faces largest|center)")
    return out + rest_warnings(actor_rest(track), list(track.blendshape_names))


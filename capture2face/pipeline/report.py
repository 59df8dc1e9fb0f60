"""``run``'s report: which outputs make a finished run, and the warnings it reports."""

from __future__ import annotations

import json
import os
from pathlib import Path

from capture2face.pipeline.options import RunOptions


def outputs_complete(folder: str | os.PathLike) -> bool:
    """True when ``folder`` holds a finished run: report.json and every output it lists."""
    folder = Path(folder)
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    names = report.get("outputs") or []
    return bool(names) and all((folder / name).is_file() and (folder / name).stat().st_size > 0 for name in names)


def track_warnings(track, options: RunOptions | None = None) -> list[str]:
    out = []
    missing = track.n_frames - track.tracked_frames
    if missing:
        out.append(f"no face in {missing} of {track.n_frames} frames ({track.n_gaps} gaps); "
                   "short gaps are interpolated, longer ones hold the last pose")
    if track.n_long_gaps:
        out.append(f"{track.n_long_gaps} gaps longer than the interpolation limit hold the last pose")
    if track.n_faces_max > 1:
        face, faces = (options.face, options.faces) if options is not None else (None, "largest")
        start = (f"face {face} from the left" if face is not None
                 else "the face nearest the centre" if faces == "center" else "the largest face")
        out.append(f"{track.n_faces_max} faces in view (the most seen at once); tracked: {start} at the start, "
                   "then the one continuing the track (choose with --face N or --faces largest|center)")
    return out


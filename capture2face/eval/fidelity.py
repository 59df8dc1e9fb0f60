"""``capture2face eval fidelity``: the expression-fidelity figures (:mod:`capture2face.measures`)
of clips, tracked and retargeted here, or of ``run`` output folders; a table, a summary
line and a picture per clip."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from capture2face.character.load import load_character
from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path
from capture2face.measures import (
    AT_REST_P99_GOAL,
    GAIN_MAX,
    GAIN_MIN,
    GAZE_R_GOAL,
    LEVEL_TOL,
    MEASURES,
    R_MIN,
    WRINKLE_R_GOAL,
    ClipFidelity,
    clip_fidelity,
)
from capture2face.pipeline import RunOptions, retarget_stage, track_stage
from capture2face.pipeline.report.figures import fidelity_line_plots
from capture2face.pipeline.report.raster import raster_plots
from capture2face.retarget.animation import Animation
from capture2face.tracking.track import Track


# ---- clips and run folders -----------------------------------------------------------------
def _load_run(folder: Path):
    missing = [f for f in ("track.npz", "animation.npz") if not (folder / f).is_file()]
    if missing:
        raise CaptureError(f"{folder}: not a run folder (no {', '.join(missing)})")
    character = _run_character(folder / "report.json")
    track, animation = Track.load(folder / "track.npz"), Animation.load(folder / "animation.npz")
    return track, animation, load_character(character)


def _run_character(path: Path) -> str | None:
    """The character file a run's report.json names (None: the default avatar, or a report
    from before characters were stored). One that cannot be read is refused: measuring
    against another character than the run's would give wrong figures without a word."""
    if not os.path.lexists(path):
        return None
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        why = "not UTF-8 text"
    except ValueError as exc:
        why = f"not valid JSON: {exc}"
    except OSError as exc:
        why = exc.strerror or str(exc)
    else:
        options = report.get("options", {}) if isinstance(report, dict) else None
        if isinstance(options, dict) and isinstance(options.get("character"), (str, type(None))):
            return options.get("character")
        why = "not a capture2face run's report"
    raise CaptureError(f"{path}: cannot be read ({why}), so the character the run used is unknown")


def fidelity_of(path: str | os.PathLike, character=None, progress: bool = False) -> ClipFidelity:
    """A clip (tracked and retargeted here, nothing rendered) or a ``run`` output folder."""
    path = Path(path)
    if path.is_dir():
        track, animation, rig = _load_run(path)
        return clip_fidelity(track, animation, rig, path.name)
    rig = load_character(character)
    with tempfile.TemporaryDirectory(prefix="capture2face-fidelity-") as work:
        track = track_stage(path, RunOptions(), progress=progress, workdir=work)
        animation = retarget_stage(track, rig)
        return clip_fidelity(track, animation, rig, path.stem)


def summary_line(results: list[dict]) -> str:
    judged = sum(r["summary"]["judged"] for r in results)
    ok = sum(r["summary"]["faithful"] for r in results)
    beats = sum(r["summary"]["not_worse_than_direct"] for r in results)
    arkit = [a for r in results for a in r["arkit"].values() if a.get("judged", True)]
    gaze = [g for r in results for g in r.get("gaze", {}).values() if g["judged"]]
    with_curves = [r["summary"]["not_worse_than_curves"] for r in results if "not_worse_than_curves" in r["summary"]]
    curves = (f", {sum(with_curves)}/{judged} not worse than the curves-only drive"
              if len(with_curves) == len(results) and results else "")
    return (f"{len(results)} clips: {ok}/{judged} judged measures faithful (r >= {R_MIN}, gain "
            f"{GAIN_MIN}-{GAIN_MAX}), {beats}/{judged} not worse than the direct scores{curves}; "
            f"ARKit curves {sum(a['met'] for a in arkit)}/{len(arkit)} meet their r goal"
            + (f"; eye yaw {sum(g['met'] for g in gaze)}/{len(gaze)} follows eyeLookIn/Out (r >= {GAZE_R_GOAL})"
               if gaze else "") + _levels_and_wrinkles(results))


def _levels_and_wrinkles(results: list[dict]) -> str:
    """The summary line's clauses on rest levels and wrinkles (clips that have them)."""
    levels = [v for r in results for v in r.get("levels", {}).values()]
    wrinkles = [r["wrinkles"] for r in results if "wrinkles" in r]
    out = ""
    if levels:
        out += (f"; levels: {sum(v['met'] for v in levels)}/{len(levels)} brow and mouth rests within "
                f"{LEVEL_TOL} IOD of the actor's")
    if wrinkles:
        out += (f"; wrinkles: {sum(w['met'] for w in wrinkles)}/{sum(w['judged'] for w in wrinkles)} checks met "
                f"(r >= {WRINKLE_R_GOAL} with the brows' raise and lowering, glabella compress p99 < "
                f"{AT_REST_P99_GOAL} where they never lower)")
    return out


def table(results: list[dict]) -> str:
    """A plain-text (Markdown) table: clip x measure, ``r / gain`` (direct in brackets;
    ``r / gain = range gain`` where judged at the head's own range, ``= range r / range
    gain`` where it is short the other way too: the brows' lowering, the mouth's narrowing,
    the lids' closing or opening, :meth:`~capture2face.measures.ClipFidelity._own_range_source`)."""
    head = "| clip | " + " | ".join(MEASURES) + " |"
    lines = [head, "|" + "---|" * (len(MEASURES) + 1)]
    for res in results:
        cells = []
        for name in MEASURES:
            m = res["measures"].get(name)
            if m is None:  # the character's landmarks for it do not move with its morph
                cells.append("left out")
                continue
            mark = "" if not m["judged"] else (" ✓" if m["faithful"] else " ✗")
            own = f" = {m['range_gain']:.2f}" if "range_gain" in m else ""
            if "range_r" in m:  # judged at its own range below (or past) its rest too
                own = f" = {m['range_r']:.2f} / {m['range_gain']:.2f}"
            cells.append(f"{m['r']:.2f} / {m['gain']:.2f}{own}{mark} ({m['direct_r']:.2f} / {m['direct_gain']:.2f})"
                         if m["judged"] else f"— ({m['range']:.3f})")
        lines.append(f"| {res['clip']} | " + " | ".join(cells) + " |")
    extra = wrinkle_table(results)
    return "\n".join(lines) + (f"\n\n{extra}" if extra else "")


def _check_cell(entry: dict, key: str, fmt: str) -> str:
    mark = (" ✓" if entry["met"] else " ✗") if entry.get("judged", True) and "met" in entry else ""
    return f"{entry[key]:{fmt}}{mark}" if entry.get("judged", True) else f"— ({entry[key]:{fmt}})"


def wrinkle_table(results: list[dict]) -> str:
    """Levels and wrinkles per clip (Markdown): the character's brow and lip offsets from the
    actor's at the actor's rest (IOD), r of forehead stretch / glabella compress with the
    brows' raise / lowering (— and the motion's 99th percentile where too small to judge),
    and glabella compress's 99th percentile where browDown never reaches 0.1."""
    rows = [r for r in results if "wrinkles" in r or "levels" in r]
    if not rows:
        return ""
    lines = ["| clip | brow level | lip level | forehead stretch r | glabella compress r | glabella p99 (unfrowned) |",
             "|---|---|---|---|---|---|"]
    for res in rows:
        lv, w = res.get("levels", {}), res.get("wrinkles", {})
        cells = [_check_cell(lv[k], "offset", "+.3f") if k in lv else "" for k in ("brows", "mouth")]
        cells += [_check_cell(w[k], "r" if w[k]["judged"] else "amount", ".2f" if w[k]["judged"] else ".3f")
                  if k in w else "" for k in ("forehead_stretch", "glabella_compress")]
        cells.append(_check_cell(w["glabella_unfrowned"], "p99", ".2f") if "glabella_unfrowned" in w else "")
        lines.append(f"| {res['clip']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ---- picture ------------------------------------------------------------------------------
def plot(fid: ClipFidelity, path: str | os.PathLike, width: int = 960, row: int = 170,
         figures: dict | None = None) -> None:
    """A PNG of report.html's fidelity plots (:func:`~capture2face.pipeline.report.figures.fidelity_line_plots`):
    each measure over time, source (black), character (orange), direct (blue), then the
    wrinkle checks; ``row`` px high each, titled with ``figures`` (default ``fid.figures()``)."""
    import cv2

    plots = fidelity_line_plots(fid, fid.figures() if figures is None else figures)
    img = raster_plots(plots, width, row)
    path = Path(path)
    with atomic_path(path) as tmp:  # keeps the .png suffix OpenCV picks the format from
        if not cv2.imwrite(str(tmp), img):
            raise CaptureError(f"{path}: cannot write the picture")


def evaluate_fidelity(paths: list[str | os.PathLike], character=None, plot_dir: str | os.PathLike | None = None,
                      progress: bool = False) -> dict:
    """Fidelity figures of clips or run folders: ``{"clips": [...], "summary": line}``.

    With ``plot_dir``, one ``<clip>.fidelity.png`` per clip is written there.
    """
    results = []
    for p in paths:
        fid = fidelity_of(p, character, progress)
        res = fid.figures()
        if plot_dir is not None:
            Path(plot_dir).mkdir(parents=True, exist_ok=True)
            picture = Path(plot_dir) / f"{fid.name}.fidelity.png"
            plot(fid, picture, figures=res)
            res["picture"] = os.fspath(picture)
        results.append(res)
    return {"clips": results, "summary": summary_line(results)}

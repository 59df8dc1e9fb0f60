"""report.html's page: its sections assembled into one self-contained document."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from capture2face.io.atomic import write_text_atomic
from capture2face.pipeline.report.figures import arkit_plots, fidelity_plots, influence_plots
from capture2face.pipeline.report.posters import (
    decode_poster_frames,
    jpeg_data_uri,
    poster_frames,
    report_curves,
    shrink,
)
from capture2face.pipeline.report.tables import (
    calibration_table,
    esc,
    facts_table,
    fidelity_tables,
    seconds_table,
    warnings_note,
)

STYLE = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;background:#f6f6f4;color:#222}
main{max-width:1160px;margin:0 auto;padding:18px 24px 40px}
h1{font-size:22px;margin:6px 0 2px}h2{font-size:17px;margin:26px 0 8px;border-bottom:1px solid #ddd;padding-bottom:3px}
.sub{color:#666;margin:0 0 12px}
table{border-collapse:collapse;background:#fff;margin:6px 0 10px}
th,td{border:1px solid #ddd;padding:3px 8px;text-align:right;white-space:nowrap}
th{background:#efefec;font-weight:600}td.l,th.l{text-align:left}
.facts td:first-child{text-align:left;color:#555}.facts td{text-align:left}
.ok{color:#1a7f37;font-weight:600}.bad{color:#b42318;font-weight:600}.na{color:#999}
.warn{background:#fff4e0;border:1px solid #f0c36d;padding:6px 12px;margin:6px 0}
.warn ul{margin:2px 0;padding-left:20px}
.posters{display:grid;grid-template-columns:repeat(2,1fr);gap:10px}.posters.square{grid-template-columns:repeat(3,1fr)}
figure{margin:0;background:#fff;border:1px solid #ddd;padding:4px}
figure img{width:100%;display:block}figcaption{font-size:12px;color:#444;padding:2px 2px 0}
.plots{display:grid;grid-template-columns:repeat(2,1fr);gap:8px}
svg.plot{width:100%;height:auto;background:#fff;border:1px solid #ddd;font-family:system-ui,sans-serif}
svg .tick{font-size:10px;fill:#666}svg .legend{font-size:11px;fill:#333}
svg .ptitle{font-size:12px;font-weight:600;fill:#222}
.note{color:#666;font-size:12px}
.cols{display:flex;gap:24px;flex-wrap:wrap;align-items:flex-start}
"""


def render_report_html(report: dict, track, animation, video: str | os.PathLike | None = None,
                       fidelity=None, frames: dict[int, np.ndarray] | None = None) -> str:
    """The page (see module doc) of one run.

    Args:
        report: the run's report (report.json's content); its ``"fidelity"`` entry, when
            present, fills the fidelity tables (else ``fidelity.figures()``).
        track: the clip's :class:`~capture2face.tracking.track.Track` (times, presence).
        animation: the :class:`~capture2face.retarget.animation.Animation`.
        video: compare.mp4 (or avatar.mp4) to take the poster frames from; None: none.
        fidelity: the :class:`~capture2face.measures.ClipFidelity` (measures over time), or None.
        frames: the poster frames already in memory (index -> RGB, e.g. kept by ``run``
            while rendering, see :func:`poster_frames`); missing ones are decoded from
            ``video``.
    """
    times = np.asarray(animation.times, np.float64)
    presence = np.asarray(animation.presence, bool)
    curves, names, curve_source = report_curves(animation, track)
    title = Path(str(report.get("clip", "clip"))).name
    posters = poster_frames(animation, report.get("neutral_frame"))
    marker_times = [float(times[i]) for i, _ in posters if i < len(times)]
    poster_html = _poster_section(posters, times, video, frames)
    arkit_svg = arkit_plots(times, presence, curves, names, marker_times)
    influence_svg = influence_plots(animation, times, presence, marker_times)
    fidelity_html = _fidelity_section(report, fidelity)
    outputs = ", ".join(esc(o) for o in report.get("outputs", []))
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{esc(title)} · capture2face report</title><style>{STYLE}</style></head><body><main>",
        f"<h1>{esc(title)}</h1>",
        (f'<p class="sub">{esc(report.get("character", ""))} · {esc(report.get("wrinkles", ""))} wrinkles · '
         f'{esc(report.get("frames", ""))} frames at {float(report.get("fps", 0)):.2f} fps</p>'),
        warnings_note(report),
        (f'<div class="cols"><div>{facts_table(report)}</div><div>{seconds_table(report.get("seconds") or {})}'
         "</div></div>"),
        *(["<h2>Calibration</h2>", calibration_table(report["calibration"])] if report.get("calibration") else []),
        "<h2>Frames</h2>", poster_html,
        "<h2>Expression fidelity</h2>", fidelity_html,
        ("<h2>ARKit curves</h2><p class=\"note\">From the "
         f"{'retargeted animation' if curve_source == 'animation' else 'tracker (MediaPipe scores)'}; "
         "gaps: frames without a face.</p>"),
        f'<div class="plots">{"".join(arkit_svg)}</div>',
        ("<h2>Wrinkle influence</h2><p class=\"note\">Mean per-vertex reference-pose influence over each "
         "region (Animation.region_influence).</p>"),
        "".join(influence_svg),
        f'<p class="note">Outputs: {outputs}</p>',
        "</main></body></html>",
    ]
    return "\n".join(parts) + "\n"


def _poster_section(posters: list[tuple[int, str]], times: np.ndarray, video: str | os.PathLike | None,
                    frames: dict[int, np.ndarray] | None) -> str:
    """The poster frames as JPEG figures (those in ``frames``, the rest decoded from
    ``video``), or a note that there are none."""
    poster_html = '<p class="note">No video to take frames from.</p>'
    images = {i: shrink(frames[i]) for i, _ in posters if frames and i in frames}
    missing = [i for i, _ in posters if i not in images]
    if video is not None and missing and Path(video).is_file():
        images.update(decode_poster_frames(video, missing))
    if images:
        figs = []
        for i, why in posters:
            if i not in images:
                continue
            t = float(times[i]) if i < len(times) else 0.0
            figs.append(f'<figure><img alt="frame {i}" src="{jpeg_data_uri(images[i])}">'
                        f"<figcaption>frame {i} · {t:.2f} s · {esc(why)}</figcaption></figure>")
        what = Path(video).name if video is not None else "the run's video"
        first = next(iter(images.values()))
        wide = first.shape[1] >= 2 * first.shape[0]  # compare.mp4: three panels side by side
        panels = " (source | character | wrinkle influence)" if wide else ""
        poster_html = (f'<p class="note">Frames of {esc(what)}{panels} where the expression is strongest; '
                       "dashed lines in the plots below.</p>"
                       f'<div class="posters{"" if wide else " square"}">{"".join(figs)}</div>')
    return poster_html


def _fidelity_section(report: dict, fidelity) -> str:
    """The fidelity tables (report.json's figures, else ``fidelity.figures()``) and, with
    ``fidelity``, its measures over time; else the reason there are none."""
    fig = report.get("fidelity")
    if fig is None and fidelity is not None:
        fig = fidelity.figures()
    if fig:
        fidelity_html = fidelity_tables(fig)
        if fidelity is not None:
            fidelity_html += ('<p class="note">Measures over the tracked frames, inter-ocular units (eyes: '
                              "relative to their neutral opening): the actor's landmarks (source), the "
                              "character's deformed mesh, and the rig driven directly by the tracker's "
                              "scores.</p>" + fidelity_plots(fidelity, fig))
    else:
        fidelity_html = f'<p class="note">{esc(report.get("fidelity_error", "No fidelity figures."))}</p>'
    return fidelity_html


def write_report_html(path: str | os.PathLike, report: dict, track, animation,
                      video: str | os.PathLike | None = None, fidelity=None,
                      frames: dict[int, np.ndarray] | None = None) -> None:
    """:func:`render_report_html` into ``path``, atomically."""
    write_text_atomic(path, render_report_html(report, track, animation, video, fidelity, frames))

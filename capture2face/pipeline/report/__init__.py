"""``run``'s report: which outputs make a finished run and the warnings it reports
(:mod:`.run`), and report.html, one run's report as a single self-contained page, readable
offline.

Everything is inside the page: poster frames of compare.mp4 (or avatar.mp4) as base64
JPEG data URIs (:mod:`.posters`), and every plot as inline SVG built from the arrays
(:mod:`.plots`, :mod:`.figures`; no plotting library, no script, no external stylesheet).
Contents:

* the run's facts (clip, character, frames, fps, neutral frame, warnings, seconds per stage;
  :mod:`.tables`);
* poster frames where the expression is strongest (largest jawOpen, smile, browInnerUp,
  browDown, eyeBlink, mouthPucker), plus the neutral frame;
* the expression-fidelity figures (:mod:`capture2face.measures`) as tables, and the six
  measures over time (source vs character vs direct scores);
* ARKit curves over time (``Animation.arkit_weights`` when present, else the tracker's
  scores) and the wrinkle-influence curves per region (``Animation.region_influence``).

:func:`.html.render_report_html` is pure (arrays and a report dict in, a string out, apart
from decoding the poster frames); :func:`.html.write_report_html` writes it atomically.
"""

from __future__ import annotations

from capture2face.pipeline.report.figures import ARKIT_GROUPS
from capture2face.pipeline.report.html import STYLE, render_report_html, write_report_html
from capture2face.pipeline.report.plots import (
    CHARACTER_COLOUR,
    DIRECT_COLOUR,
    PALETTE,
    SOURCE_COLOUR,
    break_gaps,
    svg_plot,
)
from capture2face.pipeline.report.posters import (
    POSTER_CUES,
    POSTER_MIN_SCORE,
    POSTER_QUALITY,
    POSTER_WIDTH,
    choose_poster_frames,
    decode_poster_frames,
    jpeg_data_uri,
    poster_frames,
    report_curves,
)
from capture2face.pipeline.report.run import check_same_clip, outputs_complete, track_warnings
from capture2face.pipeline.report.tables import STAGE_LABELS

__all__ = ["ARKIT_GROUPS", "CHARACTER_COLOUR", "DIRECT_COLOUR", "PALETTE", "POSTER_CUES", "POSTER_MIN_SCORE",
           "POSTER_QUALITY", "POSTER_WIDTH", "SOURCE_COLOUR", "STAGE_LABELS", "STYLE", "break_gaps",
           "check_same_clip", "choose_poster_frames", "decode_poster_frames", "jpeg_data_uri", "outputs_complete",
           "poster_frames", "render_report_html", "report_curves", "svg_plot", "track_warnings",
           "write_report_html"]

"""report.html's names where they were before :mod:`capture2face.pipeline.report` became a
package (re-exports; new code imports from the package)."""

from __future__ import annotations

from capture2face.pipeline.report import (
    ARKIT_GROUPS,
    CHARACTER_COLOUR,
    DIRECT_COLOUR,
    PALETTE,
    POSTER_CUES,
    POSTER_MIN_SCORE,
    POSTER_QUALITY,
    POSTER_WIDTH,
    SOURCE_COLOUR,
    STAGE_LABELS,
    STYLE,
    break_gaps,
    choose_poster_frames,
    decode_poster_frames,
    jpeg_data_uri,
    poster_frames,
    render_report_html,
    report_curves,
    svg_plot,
    write_report_html,
)

# Formerly module-private helpers that tests import by these names.
from capture2face.pipeline.report.figures import wrinkle_plots as _wrinkle_plots
from capture2face.pipeline.report.tables import facts_table as _facts_table
from capture2face.pipeline.report.tables import fidelity_tables as _fidelity_tables

__all__ = ["ARKIT_GROUPS", "CHARACTER_COLOUR", "DIRECT_COLOUR", "PALETTE", "POSTER_CUES", "POSTER_MIN_SCORE",
           "POSTER_QUALITY", "POSTER_WIDTH", "SOURCE_COLOUR", "STAGE_LABELS", "STYLE", "_facts_table",
           "_fidelity_tables", "_wrinkle_plots", "break_gaps", "choose_poster_frames", "decode_poster_frames",
           "jpeg_data_uri", "poster_frames", "render_report_html", "report_curves", "svg_plot",
           "write_report_html"]

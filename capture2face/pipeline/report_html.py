"""report.html's public names where they were before :mod:`capture2face.pipeline.report`
became a package: a compatibility re-export; new code imports from the package."""

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

__all__ = ["ARKIT_GROUPS", "CHARACTER_COLOUR", "DIRECT_COLOUR", "PALETTE", "POSTER_CUES", "POSTER_MIN_SCORE",
           "POSTER_QUALITY", "POSTER_WIDTH", "SOURCE_COLOUR", "STAGE_LABELS", "STYLE", "break_gaps",
           "choose_poster_frames", "decode_poster_frames", "jpeg_data_uri", "poster_frames", "render_report_html",
           "report_curves", "svg_plot", "write_report_html"]

"""The plots of report.html: the fidelity measures and wrinkle checks over time, the ARKit
curves and the wrinkle influence per region, as SVG (:func:`.plots.svg_plot`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from capture2face.measures import EYE_MEASURES, MEASURES
from capture2face.pipeline.report.plots import (
    CHARACTER_COLOUR,
    DIRECT_COLOUR,
    PALETTE,
    SOURCE_COLOUR,
    LinePlot,
    break_gaps,
    svg_line_plot,
    svg_plot,
)
from capture2face.pipeline.report.posters import curve_index

# Plot groups of ARKit curves (MediaPipe's spelling; matched case-insensitively).
ARKIT_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("Jaw and mouth", ("jawOpen", "mouthClose", "mouthPucker", "mouthFunnel", "jawLeft", "jawRight")),
    ("Smile and frown", ("mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight",
                         "mouthStretchLeft", "mouthStretchRight")),
    ("Eyes", ("eyeBlinkLeft", "eyeBlinkRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight")),
    ("Brows", ("browInnerUp", "browDownLeft", "browDownRight", "browOuterUpLeft", "browOuterUpRight")),
    ("Cheeks and nose", ("cheekSquintLeft", "cheekSquintRight", "cheekPuff", "noseSneerLeft", "noseSneerRight")),
)


def fidelity_line_plots(fid, fig: dict) -> list[LinePlot]:
    """The measures over time (:func:`measure_plots`) and the wrinkle checks
    (:func:`wrinkle_check_plots`): what report.html and ``eval fidelity --plots`` draw."""
    return measure_plots(fid, fig) + wrinkle_check_plots(fid, fig)


def measure_plots(fid, fig: dict) -> list[LinePlot]:
    """One plot per measure of ``fid`` (a :class:`~capture2face.measures.ClipFidelity`):
    source, character and direct scores over time, titled with ``fig``'s figures
    (``fid.figures()``)."""
    times, source, character, direct = break_gaps(fid.times, fid.source, fid.character, fid.direct)
    plots = []
    for k, name in enumerate(MEASURES):
        m = fig.get("measures", {}).get(name, {})
        title = f"{name}  r {m.get('r', 0):.2f}  gain {m.get('gain', 0):.2f}"
        plots.append(LinePlot(times, [("source", source[:, k], SOURCE_COLOUR),
                                      ("character", character[:, k], CHARACTER_COLOUR),
                                      ("direct", direct[:, k], DIRECT_COLOUR)], title=title,
                              y_label="× neutral opening" if name in EYE_MEASURES else "IOD"))
    return plots


def wrinkle_check_plots(fid, fig: dict) -> list[LinePlot]:
    """Forehead stretch against the brows' raise, glabella compress against their lowering
    (both from the actor's rest, ×10 IOD so that 0.1 IOD meets influence 1); none without
    the wrinkles' influence."""
    if getattr(fid, "wrinkles", None) is None or getattr(fid, "scores", None) is None:
        return []
    rise, lower, _ = fid.brow_motion()
    times, rise, lower, wrinkles = break_gaps(fid.times, rise, lower, fid.wrinkles)
    w = fig.get("wrinkles", {})
    plots = []
    for k, (key, label, motion) in enumerate((("forehead_stretch", "forehead stretch", rise),
                                              ("glabella_compress", "glabella compress", lower))):
        r = w.get(key, {}).get("r", 0.0)
        hi = max(1e-3, float(np.nanmax(np.concatenate([wrinkles[:, k], 10.0 * motion])))) * 1.05
        plots.append(LinePlot(times, [(f"brow {'raise' if k == 0 else 'lowering'} ×10", 10.0 * motion, SOURCE_COLOUR),
                                      (label, wrinkles[:, k], CHARACTER_COLOUR)],
                              title=f"{label}  r {r:.2f}", y_range=(0.0, hi), y_label="influence / ×10 IOD"))
    return plots


def fidelity_plots(fid, fig: dict) -> str:
    """The fidelity section's plots (:func:`fidelity_line_plots`) as SVG."""
    return f'<div class="plots">{"".join(svg_line_plot(p) for p in fidelity_line_plots(fid, fig))}</div>'


def wrinkle_plots(fid, fig: dict) -> list[str]:
    """:func:`wrinkle_check_plots` as SVG."""
    return [svg_line_plot(p) for p in wrinkle_check_plots(fid, fig)]


def _masked(values: np.ndarray, presence: np.ndarray | None) -> np.ndarray:
    v = np.asarray(values, np.float64)
    if presence is None:
        return v
    v = v.copy()
    v[~np.asarray(presence, bool)[: len(v)]] = np.nan
    return v


def arkit_plots(times: np.ndarray, presence: np.ndarray, curves: np.ndarray, names: Sequence[str],
                 marker_times: list[float]) -> list[str]:
    """One plot per :data:`ARKIT_GROUPS` group that has curves (gaps where no face was seen)."""
    index = curve_index(names)
    arkit_plots = []
    for group, wanted in ARKIT_GROUPS:
        series = [(n, _masked(curves[:, index[n.lower()]], presence), PALETTE[k % len(PALETTE)])
                  for k, n in enumerate(wanted) if n.lower() in index]
        if series:
            arkit_plots.append(svg_plot(times, series, title=group, y_range=(0.0, 1.0), markers=marker_times))
    return arkit_plots


def influence_plots(animation, times: np.ndarray, presence: np.ndarray, marker_times: list[float]) -> list[str]:
    """One wide plot per reference pose: its influence per region over time."""
    region = np.asarray(animation.region_influence, np.float64)
    influence_plots = []
    for p, pose in enumerate(animation.pose_names):
        series = [(r, _masked(region[:, k, p], presence), PALETTE[k % len(PALETTE)])
                  for k, r in enumerate(animation.region_names)]
        hi = max(0.05, float(np.nanmax(region[:, :, p])) * 1.05) if region.size else 1.0
        influence_plots.append(svg_plot(times, series, title=f"{pose} influence per region", y_range=(0.0, hi),
                                        width=1120, height=190, markers=marker_times))
    return influence_plots

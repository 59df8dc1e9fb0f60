"""Plots (:class:`~.plots.LinePlot`) drawn into an image with OpenCV from the same geometry
as their SVG (:func:`~.plots.plot_layout`, :func:`~.plots.line_runs`, the same ticks): for
pictures written as image files."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from capture2face.pipeline.report.plots import LinePlot, PlotArea, line_runs, nice_ticks, plot_layout, tick_label

_FONT_SCALE, _TICK_SCALE = 0.42, 0.36  # Hershey simplex: about 12 and 10 px high, like the SVG's text
_GREY = {"frame": "#bbbbbb", "grid": "#eeeeee", "xgrid": "#f2f2f2", "tick": "#666666", "text": "#222222",
         "marker": "#999999"}


def bgr(colour: str) -> tuple[int, int, int]:
    """A CSS ``#rrggbb`` colour as OpenCV's (blue, green, red)."""
    r, g, b = (int(colour[i:i + 2], 16) for i in (1, 3, 5))
    return b, g, r


def _ascii(text: str) -> str:
    """``text`` as the Hershey fonts can draw it (ASCII; "×" as "x")."""
    return text.replace("×", "x").encode("ascii", "replace").decode("ascii")


def _text(img: np.ndarray, text: str, x: float, y: float, colour: str, scale: float = _TICK_SCALE,
          anchor: str = "start") -> None:
    """``text`` with its baseline at ``y``, starting, centred or ending at ``x``."""
    import cv2

    text = _ascii(text)
    w = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
    x0 = x - {"start": 0, "middle": w / 2, "end": w}[anchor]
    cv2.putText(img, text, (round(x0), round(y)), cv2.FONT_HERSHEY_SIMPLEX, scale, bgr(colour), 1, cv2.LINE_AA)


def _grid(img: np.ndarray, area: PlotArea, height: int) -> None:
    """Grid lines with their tick labels and the x unit, as :func:`.plots.svg_plot` draws them."""
    import cv2

    left, top, pw, ph = area.left, area.top, area.pw, area.ph
    for t in nice_ticks(area.lo, area.hi, 4):
        y = round(float(area.sy(t)))
        cv2.line(img, (left, y), (left + pw, y), bgr(_GREY["grid"]), 1)
        _text(img, tick_label(t), left - 4, y + 3.5, _GREY["tick"], anchor="end")
    for t in nice_ticks(area.x_lo, area.x_hi, 8):
        x = round(float(area.sx(t)))
        cv2.line(img, (x, top), (x, top + ph), bgr(_GREY["xgrid"]), 1)
        _text(img, tick_label(t), x, top + ph + 14, _GREY["tick"], anchor="middle")
    _text(img, "s", left + pw, height - 2, _GREY["tick"], anchor="end")


def raster_plot(plot: LinePlot, width: int = 960, height: int = 170) -> np.ndarray:
    """(H, width, 3) uint8 BGR image of ``plot`` (H: ``height``, grown for the legend's rows)."""
    import cv2

    layout = plot_layout(plot.times, plot.series, plot.y_range, width, height)
    area = layout.area
    img = np.full((layout.height, width, 3), 255, np.uint8)
    _grid(img, area, layout.height)
    for m in plot.markers:
        if area.x_lo <= m <= area.x_hi:
            x = round(float(area.sx(m)))
            cv2.line(img, (x, area.top), (x, area.top + area.ph), bgr(_GREY["marker"]), 1)
    for (_, _, colour), y in zip(plot.series, layout.data):
        for px, py in line_runs(area, layout.x, y):
            pts = np.stack([px, py], 1).round().astype(np.int32)
            if len(pts) == 1:
                cv2.circle(img, tuple(int(v) for v in pts[0]), 2, bgr(colour), -1, cv2.LINE_AA)
            else:
                cv2.polylines(img, [pts], False, bgr(colour), 1, cv2.LINE_AA)
    cv2.rectangle(img, (area.left, area.top), (area.left + area.pw, area.top + area.ph), bgr(_GREY["frame"]), 1)
    _text(img, plot.title, area.left, 15, _GREY["text"], _FONT_SCALE)
    for lx, ly, label, colour in layout.legend:
        cv2.rectangle(img, (round(lx), ly - 5), (round(lx) + 12, ly - 3), bgr(colour), -1)
        _text(img, label, lx + 15, ly, _GREY["text"])
    if plot.y_label:
        _text(img, plot.y_label, area.left + area.pw, 15, _GREY["tick"], anchor="end")
    return img


def raster_plots(plots: Sequence[LinePlot], width: int = 960, height: int = 170) -> np.ndarray:
    """(H, width, 3) uint8 BGR: the ``plots`` one under another."""
    if not plots:
        return np.full((height, width, 3), 255, np.uint8)
    return np.vstack([raster_plot(p, width, height) for p in plots])

"""Line plots of values over time: their geometry (value ranges, ticks, legend rows, the
curves' pixel runs), drawn as inline SVG here and as an image by :mod:`.raster` from the
same geometry."""

from __future__ import annotations

import dataclasses
import html
import itertools
import math
from collections.abc import Sequence

import numpy as np

# Distinct, colour-blind-friendly line colours (Okabe-Ito, then a few extra).
PALETTE = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#882255", "#000000",
           "#999999", "#6A3D9A")
SOURCE_COLOUR, CHARACTER_COLOUR, DIRECT_COLOUR = "#222222", "#E66100", "#5D8FD6"


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """Round tick values covering [lo, hi]."""
    span = hi - lo
    if not np.isfinite(span) or span <= 0:
        return [lo]
    raw = span / max(1, count)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(first + i * step, 10) for i in range(int((hi - first) / step + 1e-9) + 1)]


def tick_label(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def decimate(x: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Min/max envelope of a polyline down to ~``max_points`` points (peaks are kept)."""
    n = len(x)
    if n <= max_points:
        return x, y
    buckets = max(1, max_points // 2)
    edges = np.linspace(0, n, buckets + 1).astype(int)
    xs, ys = [], []
    for a, b in itertools.pairwise(edges):
        if b <= a:
            continue
        seg = y[a:b]
        i, j = a + int(np.argmin(seg)), a + int(np.argmax(seg))
        for k in sorted({i, j}):
            xs.append(x[k])
            ys.append(y[k])
    return np.asarray(xs), np.asarray(ys)


@dataclasses.dataclass(frozen=True)
class PlotArea:
    """The data rectangle of an :func:`svg_plot` (px) and the value ranges it spans."""

    left: int
    top: int
    pw: int
    ph: int
    x_lo: float
    x_hi: float
    lo: float
    hi: float

    def sx(self, v):
        return self.left + (np.asarray(v, np.float64) - self.x_lo) / (self.x_hi - self.x_lo) * self.pw

    def sy(self, v):
        clipped = np.clip(np.asarray(v, np.float64), self.lo, self.hi)
        return self.top + self.ph - (clipped - self.lo) / (self.hi - self.lo) * self.ph


@dataclasses.dataclass(frozen=True)
class LinePlot:
    """One plot's content: series over time and how it is framed (see :func:`svg_plot`)."""

    times: np.ndarray  # (N,) seconds
    series: list  # (label, (N,) values, CSS colour "#rrggbb") per line
    title: str = ""
    y_range: tuple[float, float] | None = None
    markers: Sequence[float] = ()
    y_label: str = ""


def svg_plot(times: Sequence[float], series: Sequence[tuple[str, Sequence[float], str]], title: str = "",
             y_range: tuple[float, float] | None = None, width: int = 560, height: int = 170,
             markers: Sequence[float] = (), y_label: str = "") -> str:
    """An inline ``<svg>`` line plot.

    Args:
        times: (N,) x values (seconds).
        series: (label, (N,) values, CSS colour); NaN values break the line.
        title: drawn top left, followed by the legend.
        y_range: fixed (lo, hi); None: the data's range, padded.
        width, height: the SVG's size in px (it scales to its container's width); the
            height grows with the legend's rows.
        markers: x values drawn as thin vertical dashed lines (e.g. the poster frames).
        y_label: unit, drawn top right.
    Returns:
        The ``<svg>...</svg>`` text (no XML namespace: it is meant to be inlined in HTML).
    """
    layout = plot_layout(times, series, y_range, width, height)
    area, height = layout.area, layout.height
    left, top, pw, ph = area.left, area.top, area.pw, area.ph
    esc = html.escape
    out = [(f'<svg class="plot" viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
            f'role="img" aria-label="{esc(title, quote=True)}">'),
           f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="#fff" stroke="#bbb"/>']
    out += _svg_grid(area, height)
    out += _svg_markers(area, markers)
    out += _svg_lines(area, layout.x, series, layout.data)
    out += _svg_labels(area, title, layout.legend, y_label)
    out.append("</svg>")
    return "".join(out)


def svg_line_plot(plot: LinePlot, width: int = 560, height: int = 170) -> str:
    """:func:`svg_plot` of ``plot``."""
    return svg_plot(plot.times, plot.series, title=plot.title, y_range=plot.y_range, width=width, height=height,
                    markers=plot.markers, y_label=plot.y_label)


@dataclasses.dataclass(frozen=True)
class PlotLayout:
    """Where a plot's parts go (px) and its values as arrays."""

    area: PlotArea
    legend: list  # (x, y, label, colour) per legend entry
    height: int  # the plot's height, grown for the legend's rows
    x: np.ndarray  # (N,) float64
    data: list  # (N,) float64 values per series


def plot_layout(times: Sequence[float], series: Sequence[tuple[str, Sequence[float], str]],
                y_range: tuple[float, float] | None, width: int, height: int) -> PlotLayout:
    """The data rectangle, the legend and the value ranges of a ``width`` x ``height`` plot
    (arguments as :func:`svg_plot`'s)."""
    x = np.asarray(times, np.float64).reshape(-1)
    left, right, bottom = 46, 10, 22
    legend, row = legend_layout(series, left, width - right)
    top = (36 + 14 * row + 6) if legend else 24
    height = max(height, top + bottom + 80)
    pw, ph = width - left - right, height - top - bottom
    data = [np.asarray(v, np.float64).reshape(-1) for _, v, _ in series]
    lo, hi = y_limits(data, y_range)
    x_lo, x_hi = x_limits(x)
    return PlotLayout(PlotArea(left, top, pw, ph, x_lo, x_hi, lo, hi), legend, height, x, data)


def legend_layout(series, left: int, right_edge: int) -> tuple[list[tuple], int]:
    """(x, y, label, colour) per legend entry and the last row's number."""
    # Legend entries under the title, wrapped to the plot's width (text width estimated).
    legend, lx, row = [], left, 0
    for label, _, colour in series:
        w = 22 + 6.3 * len(label)
        if lx + w > right_edge and lx > left:
            lx, row = left, row + 1
        legend.append((lx, 30 + 14 * row, label, colour))
        lx += w
    return legend, row


def y_limits(data: list[np.ndarray], y_range: tuple[float, float] | None) -> tuple[float, float]:
    """``y_range``, else the finite values' range padded by 5 %; never empty."""
    finite = [d[np.isfinite(d)] for d in data]
    if y_range is not None:
        lo, hi = float(y_range[0]), float(y_range[1])
    else:
        vals = np.concatenate(finite) if finite else np.zeros(0)
        lo, hi = (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)
        pad = 0.05 * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.05
        lo, hi = lo - pad, hi + pad
    if hi <= lo:
        hi = lo + 1.0
    return lo, hi


def x_limits(x: np.ndarray) -> tuple[float, float]:
    x_lo, x_hi = (float(x.min()), float(x.max())) if x.size else (0.0, 1.0)
    if x_hi <= x_lo:
        x_hi = x_lo + 1.0
    return x_lo, x_hi


def _svg_grid(area: PlotArea, height: int) -> list[str]:
    """Horizontal and vertical grid lines with their tick labels, and the x unit."""
    left, top, pw, ph = area.left, area.top, area.pw, area.ph
    out = []
    for t in nice_ticks(area.lo, area.hi, 4):
        y = float(area.sy(t))
        out.append(f'<line x1="{left}" x2="{left + pw}" y1="{y:.1f}" y2="{y:.1f}" stroke="#eee"/>'
                   f'<text x="{left - 4}" y="{y + 3.5:.1f}" text-anchor="end" class="tick">{tick_label(t)}</text>')
    for t in nice_ticks(area.x_lo, area.x_hi, 8):
        xp = float(area.sx(t))
        out.append(f'<line x1="{xp:.1f}" x2="{xp:.1f}" y1="{top}" y2="{top + ph}" stroke="#f2f2f2"/>'
                   f'<text x="{xp:.1f}" y="{top + ph + 14}" text-anchor="middle" class="tick">{tick_label(t)}</text>')
    out.append(f'<text x="{left + pw}" y="{height - 2}" text-anchor="end" class="tick">s</text>')
    return out


def _svg_markers(area: PlotArea, markers: Sequence[float]) -> list[str]:
    """The markers inside the x range as dashed vertical lines."""
    out = []
    for m in markers:
        if area.x_lo <= m <= area.x_hi:
            xp = float(area.sx(m))
            out.append(f'<line x1="{xp:.1f}" x2="{xp:.1f}" y1="{area.top}" y2="{area.top + area.ph}" '
                       'stroke="#999" stroke-dasharray="3 3"/>')
    return out


def line_runs(area: PlotArea, x: np.ndarray, y: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(px, py) of each run of finite values of one series (NaN values break the line),
    decimated to the plot's width."""
    n = min(len(x), len(y))
    idx = np.flatnonzero(np.isfinite(y[:n]))
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    runs = []
    for run in np.split(idx, breaks):
        xs, ys = decimate(x[run], y[run], 2 * area.pw)
        runs.append((area.sx(xs), area.sy(ys)))
    return runs


def _svg_lines(area: PlotArea, x: np.ndarray, series, data: list[np.ndarray]) -> list[str]:
    """Each series as polylines (a lone finite value as a dot)."""
    esc = html.escape
    out = []
    for (_, _, colour), y in zip(series, data):
        for px, py in line_runs(area, x, y):
            if len(px) == 1:
                out.append(f'<circle cx="{px[0]:.1f}" cy="{py[0]:.1f}" r="1.5" fill="{esc(colour, quote=True)}"/>')
                continue
            pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px.tolist(), py.tolist()))
            out.append(f'<polyline points="{pts}" fill="none" stroke="{esc(colour, quote=True)}" '
                       'stroke-width="1.3" stroke-linejoin="round"/>')
    return out


def _svg_labels(area: PlotArea, title: str, legend: list[tuple], y_label: str) -> list[str]:
    """The title, the legend entries and the y unit."""
    esc = html.escape
    out = [f'<text x="{area.left}" y="15" class="ptitle">{esc(title)}</text>']
    for lx, ly, label, colour in legend:
        out.append(f'<rect x="{lx:.0f}" y="{ly - 5}" width="12" height="3" fill="{esc(colour, quote=True)}"/>'
                   f'<text x="{lx + 15:.0f}" y="{ly}" class="legend">{esc(label)}</text>')
    if y_label:
        out.append(f'<text x="{area.left + area.pw}" y="15" text-anchor="end" class="tick">{esc(y_label)}</text>')
    return out


def break_gaps(times: np.ndarray, *columns: np.ndarray) -> tuple[np.ndarray, ...]:
    """``times`` and ``columns`` (rows per time) with a NaN row inserted wherever the
    times skip more than 1.5 frames (frames without a face), so that plots break there."""
    times = np.asarray(times, np.float64)
    if len(times) < 3:
        return (times, *columns)
    dt = np.diff(times)
    at = np.flatnonzero(dt > 1.5 * np.median(dt)) + 1
    if at.size == 0:
        return (times, *columns)
    out_t = np.insert(times, at, (times[at - 1] + times[at]) / 2)
    return (out_t, *(np.insert(np.asarray(c, np.float64), at, np.nan, axis=0) for c in columns))

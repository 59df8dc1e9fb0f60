"""report.html: one run's report as a single self-contained page, readable offline.

Everything is inside the file: poster frames of compare.mp4 (or avatar.mp4) as base64
JPEG data URIs, and every plot as inline SVG built here from the arrays (no plotting
library, no script, no external stylesheet). Contents:

* the run's facts (clip, character, frames, fps, neutral frame, warnings, seconds per stage);
* poster frames where the expression is strongest (largest jawOpen, smile, browInnerUp,
  browDown, eyeBlink, mouthPucker), plus the neutral frame;
* the expression-fidelity figures (:mod:`capture2face.measures`) as tables, and the six
  measures over time (source vs character vs direct scores);
* ARKit curves over time (``Animation.arkit_weights`` when present, else the tracker's
  scores) and the wrinkle-influence curves per region (``Animation.region_influence``).

:func:`render_report_html` is pure (arrays and a report dict in, a string out, apart from
decoding the poster frames); :func:`write_report_html` writes it atomically.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from capture2face.io.atomic import write_text_atomic
from capture2face.io.video_input import iter_frames
from capture2face.measures import EYE_MEASURES, GAIN_MAX, GAIN_MIN, MEASURES, R_MIN

# Distinct, colour-blind-friendly line colours (Okabe-Ito, then a few extra).
PALETTE = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#882255", "#000000",
           "#999999", "#6A3D9A")
SOURCE_COLOUR, CHARACTER_COLOUR, DIRECT_COLOUR = "#222222", "#E66100", "#5D8FD6"

# Plot groups of ARKit curves (MediaPipe's spelling; matched case-insensitively).
ARKIT_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("Jaw and mouth", ("jawOpen", "mouthClose", "mouthPucker", "mouthFunnel", "jawLeft", "jawRight")),
    ("Smile and frown", ("mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight",
                         "mouthStretchLeft", "mouthStretchRight")),
    ("Eyes", ("eyeBlinkLeft", "eyeBlinkRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight")),
    ("Brows", ("browInnerUp", "browDownLeft", "browDownRight", "browOuterUpLeft", "browOuterUpRight")),
    ("Cheeks and nose", ("cheekSquintLeft", "cheekSquintRight", "cheekPuff", "noseSneerLeft", "noseSneerRight")),
)

# Poster cues: label -> ARKit curves whose mean picks the frame.
POSTER_CUES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("jawOpen", ("jawOpen",)),
    ("smile", ("mouthSmileLeft", "mouthSmileRight")),
    ("browInnerUp", ("browInnerUp",)),
    ("browDown", ("browDownLeft", "browDownRight")),
    ("eyeBlink", ("eyeBlinkLeft", "eyeBlinkRight")),
    ("mouthPucker", ("mouthPucker",)),
)
POSTER_MIN_SCORE = 0.15  # a cue whose strongest frame scores less shows nothing worth a poster
POSTER_WIDTH = 900  # px, the JPEGs' largest width
POSTER_QUALITY = 80


# ---- SVG plots ----------------------------------------------------------------------------
def _nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """Round tick values covering [lo, hi]."""
    span = hi - lo
    if not np.isfinite(span) or span <= 0:
        return [lo]
    raw = span / max(1, count)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(first + i * step, 10) for i in range(int((hi - first) / step + 1e-9) + 1)]


def _fmt(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def _decimate(x: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Min/max envelope of a polyline down to ~``max_points`` points (peaks are kept)."""
    n = len(x)
    if n <= max_points:
        return x, y
    buckets = max(1, max_points // 2)
    edges = np.linspace(0, n, buckets + 1).astype(int)
    xs, ys = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        if b <= a:
            continue
        seg = y[a:b]
        i, j = a + int(np.argmin(seg)), a + int(np.argmax(seg))
        for k in sorted({i, j}):
            xs.append(x[k])
            ys.append(y[k])
    return np.asarray(xs), np.asarray(ys)


@dataclasses.dataclass(frozen=True)
class _PlotArea:
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
    x = np.asarray(times, np.float64).reshape(-1)
    left, right, bottom = 46, 10, 22
    legend, row = _legend_layout(series, left, width - right)
    top = (36 + 14 * row + 6) if legend else 24
    height = max(height, top + bottom + 80)
    pw, ph = width - left - right, height - top - bottom
    data = [np.asarray(v, np.float64).reshape(-1) for _, v, _ in series]
    lo, hi = _y_limits(data, y_range)
    x_lo, x_hi = _x_limits(x)
    area = _PlotArea(left, top, pw, ph, x_lo, x_hi, lo, hi)
    esc = html.escape
    out = [f'<svg class="plot" viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
           f'role="img" aria-label="{esc(title, quote=True)}">',
           f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="#fff" stroke="#bbb"/>']
    out += _svg_grid(area, height)
    out += _svg_markers(area, markers)
    out += _svg_lines(area, x, series, data)
    out += _svg_labels(area, title, legend, y_label)
    out.append("</svg>")
    return "".join(out)


def _legend_layout(series, left: int, right_edge: int) -> tuple[list[tuple], int]:
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


def _y_limits(data: list[np.ndarray], y_range: tuple[float, float] | None) -> tuple[float, float]:
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


def _x_limits(x: np.ndarray) -> tuple[float, float]:
    x_lo, x_hi = (float(x.min()), float(x.max())) if x.size else (0.0, 1.0)
    if x_hi <= x_lo:
        x_hi = x_lo + 1.0
    return x_lo, x_hi


def _svg_grid(area: _PlotArea, height: int) -> list[str]:
    """Horizontal and vertical grid lines with their tick labels, and the x unit."""
    left, top, pw, ph = area.left, area.top, area.pw, area.ph
    out = []
    for t in _nice_ticks(area.lo, area.hi, 4):
        y = float(area.sy(t))
        out.append(f'<line x1="{left}" x2="{left + pw}" y1="{y:.1f}" y2="{y:.1f}" stroke="#eee"/>'
                   f'<text x="{left - 4}" y="{y + 3.5:.1f}" text-anchor="end" class="tick">{_fmt(t)}</text>')
    for t in _nice_ticks(area.x_lo, area.x_hi, 8):
        xp = float(area.sx(t))
        out.append(f'<line x1="{xp:.1f}" x2="{xp:.1f}" y1="{top}" y2="{top + ph}" stroke="#f2f2f2"/>'
                   f'<text x="{xp:.1f}" y="{top + ph + 14}" text-anchor="middle" class="tick">{_fmt(t)}</text>')
    out.append(f'<text x="{left + pw}" y="{height - 2}" text-anchor="end" class="tick">s</text>')
    return out


def _svg_markers(area: _PlotArea, markers: Sequence[float]) -> list[str]:
    """The markers inside the x range as dashed vertical lines."""
    out = []
    for m in markers:
        if area.x_lo <= m <= area.x_hi:
            xp = float(area.sx(m))
            out.append(f'<line x1="{xp:.1f}" x2="{xp:.1f}" y1="{area.top}" y2="{area.top + area.ph}" '
                       'stroke="#999" stroke-dasharray="3 3"/>')
    return out


def _svg_lines(area: _PlotArea, x: np.ndarray, series, data: list[np.ndarray]) -> list[str]:
    """Each series as polylines (a lone finite value as a dot), decimated to the plot's width."""
    esc = html.escape
    out = []
    max_points = 2 * area.pw
    for (label, _, colour), y in zip(series, data):
        n = min(len(x), len(y))
        ok = np.isfinite(y[:n])
        # Runs of finite values, each its own polyline.
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            continue
        breaks = np.flatnonzero(np.diff(idx) > 1) + 1
        for run in np.split(idx, breaks):
            xs, ys = _decimate(x[run], y[run], max_points)
            px, py = area.sx(xs), area.sy(ys)
            if len(px) == 1:
                out.append(f'<circle cx="{px[0]:.1f}" cy="{py[0]:.1f}" r="1.5" fill="{esc(colour, quote=True)}"/>')
                continue
            pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px.tolist(), py.tolist()))
            out.append(f'<polyline points="{pts}" fill="none" stroke="{esc(colour, quote=True)}" '
                       'stroke-width="1.3" stroke-linejoin="round"/>')
    return out


def _svg_labels(area: _PlotArea, title: str, legend: list[tuple], y_label: str) -> list[str]:
    """The title, the legend entries and the y unit."""
    esc = html.escape
    out = [f'<text x="{area.left}" y="15" class="ptitle">{esc(title)}</text>']
    for lx, ly, label, colour in legend:
        out.append(f'<rect x="{lx:.0f}" y="{ly - 5}" width="12" height="3" fill="{esc(colour, quote=True)}"/>'
                   f'<text x="{lx + 15:.0f}" y="{ly}" class="legend">{esc(label)}</text>')
    if y_label:
        out.append(f'<text x="{area.left + area.pw}" y="15" text-anchor="end" class="tick">{esc(y_label)}</text>')
    return out


# ---- poster frames ----------------------------------------------------------------------
def _curve_index(names: Sequence[str]) -> dict[str, int]:
    return {str(n).lower(): i for i, n in enumerate(names)}


def report_curves(animation, track=None) -> tuple[np.ndarray, list[str], str]:
    """(F, A) ARKit curves, their names and where they come from ("animation": the
    retargeted ``Animation.arkit_weights``; else "tracker": MediaPipe's scores)."""
    weights = getattr(animation, "arkit_weights", None)
    if weights is not None:
        return np.asarray(weights), list(animation.arkit_names), "animation"
    if animation is not None and getattr(animation, "mediapipe_blendshapes", None) is not None:
        return np.asarray(animation.mediapipe_blendshapes), list(animation.mediapipe_blendshape_names), "tracker"
    return np.asarray(track.blendshapes), list(track.blendshape_names), "tracker"


def choose_poster_frames(curves: np.ndarray, names: Sequence[str], presence: np.ndarray | None = None,
                         neutral: int | None = None, count: int = 6) -> list[tuple[int, str]]:
    """Up to ``count`` (frame, reason) pairs, sorted by frame: the neutral frame, then the
    frame where each :data:`POSTER_CUES` curve peaks (frames closer than 1/12 of the clip
    to one already chosen are skipped), filled with evenly spread frames to at least 4."""
    curves = np.asarray(curves)  # (F, A) as stored (float32): no whole-clip float64 copy
    n = len(curves)
    if n == 0:
        return []
    gap = max(1, n // 12)
    valid = np.ones(n, bool) if presence is None else np.asarray(presence, bool)[:n].copy()
    taken = np.zeros(n, bool)
    chosen: list[tuple[int, str]] = []

    def take(i: int, why: str) -> None:
        chosen.append((int(i), why))
        taken[max(0, i - gap):i + gap + 1] = True

    if neutral is not None and 0 <= neutral < n:
        take(int(neutral), "neutral")
    index = _curve_index(names)
    for label, cue in POSTER_CUES:
        if len(chosen) >= count:
            break
        cols = [index[c.lower()] for c in cue if c.lower() in index]
        if not cols:
            continue
        score = curves[:, cols].mean(1)
        score = np.where(valid & ~taken & np.isfinite(score), score, -np.inf)
        i = int(np.argmax(score))
        if score[i] >= POSTER_MIN_SCORE:
            take(i, f"{label} {score[i]:.2f}")
    for i in np.linspace(0, n - 1, max(2, count)).round().astype(int):
        if len(chosen) >= min(4, count):
            break
        if not taken[i]:
            take(int(i), "spread")
    return sorted(chosen)


def poster_frames(animation, neutral: int | None = None, count: int = 6) -> list[tuple[int, str]]:
    """:func:`choose_poster_frames` of a run's animation (what ``run`` keeps while rendering)."""
    curves, names, _ = report_curves(animation)
    return choose_poster_frames(curves, names, animation.presence, neutral, count)


def decode_poster_frames(video: str | os.PathLike, frames: Sequence[int],
                         max_width: int = POSTER_WIDTH) -> dict[int, np.ndarray]:
    """frame index -> RGB image of the wanted frames of ``video`` (the project's decoder;
    stops after the last wanted one), scaled down to ``max_width``."""
    wanted = set(int(i) for i in frames)
    out: dict[int, np.ndarray] = {}
    if not wanted:
        return out
    for i, (_, rgb) in enumerate(iter_frames(video, max_frames=max(wanted) + 1)):
        if i in wanted:
            out[i] = _shrink(rgb, max_width)
    return out


def _shrink(rgb: np.ndarray, max_width: int = POSTER_WIDTH) -> np.ndarray:
    import cv2

    h, w = rgb.shape[:2]
    if w <= max_width:
        return rgb
    return cv2.resize(rgb, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)


def jpeg_data_uri(rgb: np.ndarray, quality: int = POSTER_QUALITY) -> str:
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


# ---- page --------------------------------------------------------------------------------
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


def _e(value) -> str:
    return html.escape(str(value))


def _mark(flag, judged: bool = True) -> str:
    if not judged:
        return '<span class="na">—</span>'
    return '<span class="ok">yes</span>' if flag else '<span class="bad">no</span>'


def _facts_table(report: dict) -> str:
    rows = [
        ("clip", report.get("clip", "")),
        ("character", report.get("character", "")),
        ("wrinkle driver", report.get("wrinkles", "")),
        ("frames", f"{report.get('frames', '?')} ({report.get('tracked_frames', '?')} with a face)"),
        ("fps", f"{float(report.get('fps', 0)):.3f}"),
        ("neutral frame", report.get("neutral_frame", "")),
        *_rest_rows(report.get("rest")),
        ("source size", " × ".join(str(v) for v in report.get("source_size", []))),
        ("render size", report.get("size", "")),
        ("video", ", ".join(f"{k} {v}" for k, v in (report.get("video") or {}).items())),
        ("processing", f"{float(report.get('fps_processing', 0)):.1f} frames/s"),
    ]
    body = "".join(f"<tr><td>{_e(k)}</td><td>{_e(v)}</td></tr>" for k, v in rows)
    return f'<table class="facts">{body}</table>'


def _frame_span(frames: list[int]) -> str:
    """"5-12, 30-33 (12 frames)": runs of consecutive frames."""
    if not frames:
        return "none"
    runs, start = [], frames[0]
    for a, b in zip(frames, frames[1:] + [None]):
        if b != a + 1:
            runs.append(f"{start}" if start == a else f"{start}–{a}")
            start = b
    shown = ", ".join(runs[:6]) + (", …" if len(runs) > 6 else "")
    return f"{shown} ({len(frames)} frame{'s' if len(frames) != 1 else ''})"


def _rest_rows(rest: dict | None) -> list[tuple[str, str]]:
    """report.json's ``rest``: where each region's rest came from (its frames, or the take)."""
    if not rest:
        return []
    source = rest.get("source", "clip")
    if source != "clip" and not source.startswith("frame"):
        return [("rest", f"from the {source} (every region)")]
    rows = []
    for region in ("brows", "eyes", "mouth", "face"):
        entry = rest.get(region) or {}
        figures = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in entry.items() if k != "frames")
        label = "rest: whole face" if region == "face" else f"rest: {region}"
        rows.append((label, _frame_span(list(entry.get("frames", []))) + (f"; {figures}" if figures else "")))
    return rows


STAGE_LABELS = {"render_gl": "\u2003of which GL drawing", "render_encode": "render + compose + encode",
                "fidelity": "fidelity figures"}


def _seconds_table(seconds: dict) -> str:
    if not seconds:
        return ""
    total = float(seconds.get("total") or 0.0)
    rows = []
    for k, v in seconds.items():
        share = f"{100 * float(v) / total:.0f}%" if total > 0 and k != "total" else ""
        label = STAGE_LABELS.get(k, k)
        rows.append(f'<tr><td class="l">{_e(label)}</td><td>{float(v):.3f}</td><td>{share}</td></tr>')
    return ('<table><tr><th class="l">stage</th><th>seconds</th><th>of total</th></tr>' + "".join(rows)
            + "</table>")


def _warnings(report: dict) -> str:
    warnings = report.get("warnings") or []
    if not warnings:
        return '<p class="note">No warnings.</p>'
    return '<div class="warn"><b>Warnings</b><ul>' + "".join(f"<li>{_e(w)}</li>" for w in warnings) + "</ul></div>"


def _fidelity_tables(fig: dict) -> str:
    rows = []
    for name, m in fig.get("measures", {}).items():
        judged = bool(m.get("judged"))
        rows.append(
            f'<tr><td class="l">{_e(name)}</td><td>{m["range"]:.3f}</td><td>{_mark(judged)}</td>'
            f'<td class="r">{m["r"]:.3f}</td><td class="gain">{m["gain"]:.3f}</td>'
            f'<td>{_mark(m.get("faithful"), judged)}</td>'
            f'<td>{m["direct_r"]:.3f}</td><td>{m["direct_gain"]:.3f}</td>'
            f'<td>{_mark(m.get("direct_faithful"), judged)}</td></tr>')
    measures = (
        '<table class="fidelity"><tr><th class="l" rowspan="2">measure</th><th rowspan="2">source range</th>'
        '<th rowspan="2">judged</th><th colspan="3">character</th><th colspan="3">direct scores</th></tr>'
        "<tr><th>r</th><th>gain</th><th>faithful</th><th>r</th><th>gain</th><th>faithful</th></tr>"
        + "".join(rows) + "</table>")
    arows = "".join(
        f'<tr><td class="l">{_e(name)}</td><td class="l">{_e(a["against"])}</td><td>{a["r"]:.3f}</td>'
        f'<td>{a["goal"]:.2f}</td><td>{a["max"]:.3f}</td><td>{_mark(a.get("met"))}</td></tr>'
        for name, a in fig.get("arkit", {}).items())
    arkit = ('<table class="arkit"><tr><th class="l">ARKit curve</th><th class="l">against</th><th>r</th>'
             f"<th>goal</th><th>max</th><th>met</th></tr>{arows}</table>"
             f'<p class="note">curves from the {_e(fig.get("arkit_source", "?"))}</p>') if arows else ""
    s = fig.get("summary", {})
    summary = (f'<p><b>{s.get("faithful", 0)} of {s.get("judged", 0)}</b> judged measures faithful '
               f"(r ≥ {R_MIN}, gain {GAIN_MIN}–{GAIN_MAX}); {s.get('not_worse_than_direct', 0)} of "
               f"{s.get('judged', 0)} not worse than the direct scores "
               f"({fig.get('frames', 0)} tracked frames).</p>")
    left_out = fig.get("left_out") or {}
    if left_out:  # the character's landmarks for them do not move with its morphs
        summary += ('<p class="note">Left out: ' + "; ".join(f"{_e(k)} ({_e(v)})" for k, v in left_out.items())
                    + ".</p>")
    return summary + f'<div class="cols"><div>{measures}</div><div>{arkit}</div></div>' + _wrinkle_table(fig)


def _wrinkle_table(fig: dict) -> str:
    """Levels (the character's brows and lips at the actor's rest) and wrinkle checks
    (``figures()["levels"]``, ``["wrinkles"]``) as one table; "" without them."""
    rows = []
    for region, lv in fig.get("levels", {}).items():
        rows.append(f'<tr><td class="l">{_e(region)} level (offset at the actor\'s rest, IOD)</td>'
                    f'<td>{lv["offset"]:+.3f}</td><td>± {lv["tolerance"]:.2f}</td>'
                    f'<td>{_mark(lv.get("met"))}</td></tr>')
    w = fig.get("wrinkles", {})
    for key, what in (("forehead_stretch", "forehead stretch r with brow raise"),
                      ("glabella_compress", "glabella compress r with brow lowering")):
        if key in w:
            e = w[key]
            value = f'{e["r"]:.3f}' if e["judged"] else f'— (moves {e["amount"]:.3f} IOD)'
            rows.append(f'<tr><td class="l">{what}</td><td>{value}</td><td>{e.get("goal", "")}</td>'
                        f'<td>{_mark(e.get("met"), e["judged"])}</td></tr>')
    if "glabella_unfrowned" in w:
        e = w["glabella_unfrowned"]
        goal = f'&lt; {e["goal"]}' if e["judged"] else ""
        rows.append(f'<tr><td class="l">glabella compress p99, brows never lowered (browDown max '
                    f'{e["brow_down_max"]:.2f})</td><td>{e["p99"]:.3f}</td><td>{goal}'
                    f'</td><td>{_mark(e.get("met"), e["judged"])}</td></tr>')
    if not rows:
        return ""
    rest = f' (brow rest {w["brow_rest"]:.3f} IOD)' if "brow_rest" in w else ""
    return (f'<p class="note">Levels and wrinkles, measured from the actor\'s rest: the most relaxed tenth of the '
            f"frames by the region's scores{rest}.</p>"
            '<table class="fidelity"><tr><th class="l">check</th><th>figure</th><th>goal</th><th>met</th></tr>'
            + "".join(rows) + "</table>")


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


def _fidelity_plots(fid, fig: dict) -> str:
    times, source, character, direct = break_gaps(fid.times, fid.source, fid.character, fid.direct)
    plots = []
    for k, name in enumerate(MEASURES):
        m = fig.get("measures", {}).get(name, {})
        title = f"{name}  r {m.get('r', 0):.2f}  gain {m.get('gain', 0):.2f}"
        plots.append(svg_plot(times, [("source", source[:, k], SOURCE_COLOUR),
                                      ("character", character[:, k], CHARACTER_COLOUR),
                                      ("direct", direct[:, k], DIRECT_COLOUR)], title=title,
                              y_label="× neutral opening" if name in EYE_MEASURES else "IOD"))
    return f'<div class="plots">{"".join(plots + _wrinkle_plots(fid, fig))}</div>'


def _wrinkle_plots(fid, fig: dict) -> list[str]:
    """Forehead stretch against the brows' raise, glabella compress against their lowering
    (both from the actor's rest, ×10 IOD so that 0.1 IOD meets influence 1)."""
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
        plots.append(svg_plot(times, [(f"brow {'raise' if k == 0 else 'lowering'} ×10", 10.0 * motion, SOURCE_COLOUR),
                                      (label, wrinkles[:, k], CHARACTER_COLOUR)],
                              title=f"{label}  r {r:.2f}", y_range=(0.0, hi), y_label="influence / ×10 IOD"))
    return plots


def _masked(values: np.ndarray, presence: np.ndarray | None) -> np.ndarray:
    v = np.asarray(values, np.float64)
    if presence is None:
        return v
    v = v.copy()
    v[~np.asarray(presence, bool)[: len(v)]] = np.nan
    return v


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
    arkit_plots = _arkit_plots(times, presence, curves, names, marker_times)
    influence_plots = _influence_plots(animation, times, presence, marker_times)
    fidelity_html = _fidelity_section(report, fidelity)
    outputs = ", ".join(_e(o) for o in report.get("outputs", []))
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(title)} · capture2face report</title><style>{STYLE}</style></head><body><main>",
        f"<h1>{_e(title)}</h1>",
        f'<p class="sub">{_e(report.get("character", ""))} · {_e(report.get("wrinkles", ""))} wrinkles · '
        f'{_e(report.get("frames", ""))} frames at {float(report.get("fps", 0)):.2f} fps</p>',
        _warnings(report),
        f'<div class="cols"><div>{_facts_table(report)}</div><div>{_seconds_table(report.get("seconds") or {})}'
        "</div></div>",
        "<h2>Frames</h2>", poster_html,
        "<h2>Expression fidelity</h2>", fidelity_html,
        "<h2>ARKit curves</h2><p class=\"note\">From the "
        f"{'retargeted animation' if curve_source == 'animation' else 'tracker (MediaPipe scores)'}; "
        "gaps: frames without a face.</p>",
        f'<div class="plots">{"".join(arkit_plots)}</div>',
        "<h2>Wrinkle influence</h2><p class=\"note\">Mean per-vertex reference-pose influence over each "
        "region (Animation.region_influence).</p>",
        "".join(influence_plots),
        f'<p class="note">Outputs: {outputs}</p>',
        "</main></body></html>",
    ]
    return "\n".join(parts) + "\n"


def _poster_section(posters: list[tuple[int, str]], times: np.ndarray, video: str | os.PathLike | None,
                    frames: dict[int, np.ndarray] | None) -> str:
    """The poster frames as JPEG figures (those in ``frames``, the rest decoded from
    ``video``), or a note that there are none."""
    poster_html = '<p class="note">No video to take frames from.</p>'
    images = {i: _shrink(frames[i]) for i, _ in posters if frames and i in frames}
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
                        f"<figcaption>frame {i} · {t:.2f} s · {_e(why)}</figcaption></figure>")
        what = Path(video).name if video is not None else "the run's video"
        first = next(iter(images.values()))
        wide = first.shape[1] >= 2 * first.shape[0]  # compare.mp4: three panels side by side
        panels = " (source | character | wrinkle influence)" if wide else ""
        poster_html = (f'<p class="note">Frames of {_e(what)}{panels} where the expression is strongest; '
                       "dashed lines in the plots below.</p>"
                       f'<div class="posters{"" if wide else " square"}">{"".join(figs)}</div>')
    return poster_html


def _arkit_plots(times: np.ndarray, presence: np.ndarray, curves: np.ndarray, names: Sequence[str],
                 marker_times: list[float]) -> list[str]:
    """One plot per :data:`ARKIT_GROUPS` group that has curves (gaps where no face was seen)."""
    index = _curve_index(names)
    arkit_plots = []
    for group, wanted in ARKIT_GROUPS:
        series = [(n, _masked(curves[:, index[n.lower()]], presence), PALETTE[k % len(PALETTE)])
                  for k, n in enumerate(wanted) if n.lower() in index]
        if series:
            arkit_plots.append(svg_plot(times, series, title=group, y_range=(0.0, 1.0), markers=marker_times))
    return arkit_plots


def _influence_plots(animation, times: np.ndarray, presence: np.ndarray, marker_times: list[float]) -> list[str]:
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


def _fidelity_section(report: dict, fidelity) -> str:
    """The fidelity tables (report.json's figures, else ``fidelity.figures()``) and, with
    ``fidelity``, its measures over time; else the reason there are none."""
    fig = report.get("fidelity")
    if fig is None and fidelity is not None:
        fig = fidelity.figures()
    if fig:
        fidelity_html = _fidelity_tables(fig)
        if fidelity is not None:
            fidelity_html += ('<p class="note">Measures over the tracked frames, inter-ocular units (eyes: '
                              "relative to their neutral opening): the actor's landmarks (source), the "
                              "character's deformed mesh, and the rig driven directly by the tracker's "
                              "scores.</p>" + _fidelity_plots(fidelity, fig))
    else:
        fidelity_html = f'<p class="note">{_e(report.get("fidelity_error", "No fidelity figures."))}</p>'
    return fidelity_html


def write_report_html(path: str | os.PathLike, report: dict, track, animation,
                      video: str | os.PathLike | None = None, fidelity=None,
                      frames: dict[int, np.ndarray] | None = None) -> None:
    """:func:`render_report_html` into ``path``, atomically."""
    write_text_atomic(path, render_report_html(report, track, animation, video, fidelity, frames))

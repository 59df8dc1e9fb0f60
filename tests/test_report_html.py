"""report.html's parts on small arrays (the page of a real run: tests/test_pipeline.py)."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np


def _points(svg: str) -> list[np.ndarray]:
    return [np.array([[float(v) for v in p.split(",")] for p in m.split()])
            for m in re.findall(r'<polyline points="([^"]+)"', svg)]


def test_svg_plot_draws_each_series_inside_its_frame():
    from capture2face.pipeline.report import svg_plot

    t = np.linspace(0.0, 2.0, 11)
    up, down = t / 2, 1 - t / 2
    svg = svg_plot(t, [("up", up, "#f00"), ("a <b> & c", down, "#00f")], title="T<1>", y_range=(0, 1),
                   width=300, height=120, markers=[1.0])
    assert svg.startswith("<svg") and svg.endswith("</svg>") and "http" not in svg
    assert "T&lt;1&gt;" in svg and "a &lt;b&gt; &amp; c" in svg and "<b>" not in svg
    lines = _points(svg)
    assert len(lines) == 2 and all(len(p) == 11 for p in lines)
    width, height = (float(v) for v in re.search(r'viewBox="0 0 ([0-9.]+) ([0-9.]+)"', svg).groups())
    for p in lines:
        assert (p[:, 0] >= 0).all() and (p[:, 0] <= width).all() and (p[:, 1] >= 0).all() and (p[:, 1] <= height).all()
    # x grows with time; y is flipped (SVG y down): "up" ends higher than it starts.
    assert np.all(np.diff(lines[0][:, 0]) > 0)
    assert lines[0][-1, 1] < lines[0][0, 1] and lines[1][-1, 1] > lines[1][0, 1]
    np.testing.assert_allclose(lines[0][:, 1] + lines[1][:, 1], 2 * lines[0][5, 1], atol=0.11)  # mirror images
    assert svg.count("stroke-dasharray") == 1  # the marker


def test_svg_plot_breaks_lines_at_nan_and_keeps_peaks_when_decimating():
    from capture2face.pipeline.report import svg_plot

    y = np.array([0.0, 1.0, np.nan, np.nan, 2.0, 3.0, 4.0])
    assert len(_points(svg_plot(np.arange(7.0), [("y", y, "#000")]))) == 2
    assert "<polyline" not in svg_plot(np.arange(3.0), [("y", np.full(3, np.nan), "#000")])
    # 20000 samples with one spike: far fewer points, the spike still drawn at the top.
    t = np.linspace(0, 100, 20000)
    y = np.zeros_like(t)
    y[12345] = 1.0
    svg = svg_plot(t, [("y", y, "#000")], y_range=(0, 1), width=400, height=100)
    (p,) = _points(svg)
    assert len(p) < 1000
    assert p[:, 1].min() == min(float(v) for v in re.findall(r'<rect x="\d+" y="([0-9.]+)"', svg)[:1])


def test_poster_frames_pick_the_strongest_expressions():
    from capture2face.pipeline.report import choose_poster_frames

    n = 120
    names = ["jawOpen", "browInnerUp", "eyeBlinkLeft", "eyeBlinkRight"]
    curves = np.zeros((n, 4))
    curves[30, 0] = 0.9  # mouth open at 30
    curves[31, 1] = 0.8  # brows up right beside: too close, the next best brow frame wins
    curves[80, 1] = 0.5
    curves[100, 2:] = 1.0  # blink
    presence = np.ones(n, bool)
    presence[100] = False  # ... in a frame without a face: not shown
    curves[60, 2:] = 0.6
    got = choose_poster_frames(curves, names, presence, neutral=5)
    frames = [i for i, _ in got]
    assert frames == sorted(frames) and frames[:1] == [5]
    assert {30, 80, 60} <= set(frames) and 31 not in frames and 100 not in frames
    assert 4 <= len(got) <= 6
    # Nothing expressive: evenly spread frames fill up to four.
    assert len(choose_poster_frames(np.zeros((n, 4)), names)) == 4


def test_page_without_video_or_fidelity_still_renders():
    from capture2face.pipeline.report import render_report_html

    n = 40
    anim = SimpleNamespace(
        times=np.arange(n) / 25.0, presence=np.ones(n, bool),
        mediapipe_blendshapes=np.random.default_rng(0).random((n, 3)),
        mediapipe_blendshape_names=["jawOpen", "browInnerUp", "eyeBlinkLeft"],
        region_names=["forehead", "glabella"], pose_names=["stretch", "compress"],
        region_influence=np.random.default_rng(1).random((n, 2, 2)),
    )
    report = {"clip": "/x/<odd> & name.mp4", "character": "c", "frames": n, "fps": 25.0, "neutral_frame": 0,
              "warnings": ["no face in <3> frames"], "seconds": {"track": 1.0, "total": 2.0}, "outputs": []}
    page = render_report_html(report, None, anim, video=None, fidelity=None)
    assert "&lt;odd&gt; &amp; name.mp4" in page and "no face in &lt;3&gt; frames" in page
    assert "<odd>" not in page and "data:image" not in page
    assert page.count("<svg") == 3 + 2  # three ARKit groups with curves, stretch and compress


def test_break_gaps_inserts_a_nan_row_where_frames_are_missing():
    from capture2face.pipeline.report import break_gaps

    t = np.array([0.0, 0.1, 0.2, 0.9, 1.0])
    v = np.arange(10.0).reshape(5, 2)
    bt, bv = break_gaps(t, v)
    np.testing.assert_allclose(bt, [0.0, 0.1, 0.2, 0.55, 0.9, 1.0])
    assert np.isnan(bv[3]).all() and np.isfinite(np.delete(bv, 3, 0)).all()
    np.testing.assert_array_equal(break_gaps(t[:3], v[:3])[1], v[:3])  # no gap: unchanged


def test_facts_say_where_each_regions_rest_came_from():
    """report.html's facts name each region's rest frames (as runs) and its geometry, or
    the take it came from."""
    from capture2face.pipeline.report.tables import facts_table

    rest = {"source": "clip", "brows": {"frames": [5, 6, 7, 8, 30], "brow_height": 0.31, "largest_score": 0.3},
            "eyes": {"frames": [1]}, "mouth": {"frames": []}, "face": {"frames": [0, 1, 2]}}
    html = facts_table({"rest": rest})
    assert "<td>rest: brows</td><td>5–8, 30 (5 frames); brow height 0.31, largest score 0.3</td>" in html
    assert "<td>rest: eyes</td><td>1 (1 frame)</td>" in html and "<td>rest: mouth</td><td>none</td>" in html
    assert "<td>rest: whole face</td><td>0–2 (3 frames)</td>" in html
    assert "from the image /a/b.jpg (every region)" in facts_table({"rest": {"source": "image /a/b.jpg"}})


def test_the_raster_picture_draws_the_svg_geometry():
    from capture2face.pipeline.report.plots import LinePlot, line_runs, plot_layout
    from capture2face.pipeline.report.raster import bgr, raster_plot, raster_plots

    t = np.linspace(0.0, 2.0, 50)
    y = np.where(t < 1.0, t, np.nan)  # a gap: two runs would be one without it
    y[-10:] = 0.5
    plot = LinePlot(t, [("up", y, "#E66100")], title="a × b", y_range=(0.0, 1.0))
    img = raster_plot(plot, width=400, height=120)
    layout = plot_layout(plot.times, plot.series, plot.y_range, 400, 120)
    assert img.shape == (layout.height, 400, 3) and img.dtype == np.uint8
    runs = line_runs(layout.area, layout.x, layout.data[0])
    assert len(runs) == 2
    for px, py in runs:  # each run's inner points are drawn in the series' colour (antialiased)
        ink = img[np.round(py[1:-1]).astype(int), np.round(px[1:-1]).astype(int)].astype(int)
        assert np.mean(np.abs(ink - bgr("#E66100")).sum(1) < 150) > 0.9
    assert raster_plots([plot, plot], width=400, height=120).shape == (2 * layout.height, 400, 3)

"""The tables of report.html: the run's facts, seconds per stage, warnings, and the
expression-fidelity figures."""

from __future__ import annotations

import html

from capture2face.measures import GAIN_MAX, GAIN_MIN, R_MIN


def esc(value) -> str:
    return html.escape(str(value))


def _mark(flag, judged: bool = True) -> str:
    if not judged:
        return '<span class="na">—</span>'
    return '<span class="ok">yes</span>' if flag else '<span class="bad">no</span>'


def facts_table(report: dict) -> str:
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
    body = "".join(f"<tr><td>{esc(k)}</td><td>{esc(v)}</td></tr>" for k, v in rows)
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


def seconds_table(seconds: dict) -> str:
    if not seconds:
        return ""
    total = float(seconds.get("total") or 0.0)
    rows = []
    for k, v in seconds.items():
        share = f"{100 * float(v) / total:.0f}%" if total > 0 and k != "total" else ""
        label = STAGE_LABELS.get(k, k)
        rows.append(f'<tr><td class="l">{esc(label)}</td><td>{float(v):.3f}</td><td>{share}</td></tr>')
    return ('<table><tr><th class="l">stage</th><th>seconds</th><th>of total</th></tr>' + "".join(rows)
            + "</table>")


def warnings_note(report: dict) -> str:
    warnings = report.get("warnings") or []
    if not warnings:
        return '<p class="note">No warnings.</p>'
    return '<div class="warn"><b>Warnings</b><ul>' + "".join(f"<li>{esc(w)}</li>" for w in warnings) + "</ul></div>"


def fidelity_tables(fig: dict) -> str:
    rows = []
    for name, m in fig.get("measures", {}).items():
        judged = bool(m.get("judged"))
        rows.append(
            f'<tr><td class="l">{esc(name)}</td><td>{m["range"]:.3f}</td><td>{_mark(judged)}</td>'
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
        f'<tr><td class="l">{esc(name)}</td><td class="l">{esc(a["against"])}</td><td>{a["r"]:.3f}</td>'
        f'<td>{a["goal"]:.2f}</td><td>{a["max"]:.3f}</td><td>{_mark(a.get("met"))}</td></tr>'
        for name, a in fig.get("arkit", {}).items())
    arkit = ('<table class="arkit"><tr><th class="l">ARKit curve</th><th class="l">against</th><th>r</th>'
             f"<th>goal</th><th>max</th><th>met</th></tr>{arows}</table>"
             f'<p class="note">curves from the {esc(fig.get("arkit_source", "?"))}</p>') if arows else ""
    s = fig.get("summary", {})
    summary = (f'<p><b>{s.get("faithful", 0)} of {s.get("judged", 0)}</b> judged measures faithful '
               f"(r ≥ {R_MIN}, gain {GAIN_MIN}–{GAIN_MAX}); {s.get('not_worse_than_direct', 0)} of "
               f"{s.get('judged', 0)} not worse than the direct scores "
               f"({fig.get('frames', 0)} tracked frames).</p>")
    left_out = fig.get("left_out") or {}
    if left_out:  # the character's landmarks for them do not move with its morphs
        summary += ('<p class="note">Left out: ' + "; ".join(f"{esc(k)} ({esc(v)})" for k, v in left_out.items())
                    + ".</p>")
    return summary + f'<div class="cols"><div>{measures}</div><div>{arkit}</div></div>' + _wrinkle_table(fig)


def _wrinkle_table(fig: dict) -> str:
    """Levels (the character's brows and lips at the actor's rest) and wrinkle checks
    (``figures()["levels"]``, ``["wrinkles"]``) as one table; "" without them."""
    rows = []
    for region, lv in fig.get("levels", {}).items():
        rows.append(f'<tr><td class="l">{esc(region)} level (offset at the actor\'s rest, IOD)</td>'
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


def _reading(values: dict, names: list[str]) -> str:
    return ", ".join(f"{esc(n)} {float(values[n]):.2f}" for n in names if n in values) or "—"


def calibration_table(section: dict | None) -> str:
    """report.json's ``calibration``: each protocol step, the frames it was found at, how
    like the step the tracker's reading was, and its main curves before and after; "" without."""
    if not section:
        return ""
    rows = []
    for s in section.get("steps", []):
        after = s.get("after") or {}
        names = sorted(after, key=lambda n: -abs(float(after[n])))[:3]  # the step's strongest curves
        frames = "–".join(str(f) for f in s["frames"]) if s.get("frames") else "not found"
        match = f'{s["match"]:.2f}' if s.get("match") is not None else ""
        rows.append(f'<tr><td class="l">{esc(s["name"])}</td><td>{frames}</td><td>{match}</td>'
                    f'<td class="l">{_reading(s.get("before") or {}, names)}</td>'
                    f'<td class="l">{_reading(after, names)}</td></tr>')
    found = sum(1 for s in section.get("steps", []) if s.get("found"))
    return (f'<p class="note">From {esc(section.get("source", ""))}: {found} of {len(rows)} steps found, '
            f'{len(section.get("curves", {}))} curves calibrated. Match: how like the step the tracker read the '
            "hold (1 = alike). Reading: the step's strongest curves at its hold, before and after.</p>"
            '<table class="calibration"><tr><th class="l">step</th><th>frames</th><th>match</th>'
            '<th class="l">tracker before</th><th class="l">after</th></tr>' + "".join(rows) + "</table>"
            + _more_takes(section.get("more_takes") or []))


def _more_takes(takes: list[dict]) -> str:
    """The further takes of a calibration of several, a table each."""
    if not takes:
        return ""
    return (f'<p class="note">The curves are the mean of {len(takes) + 1} takes\' readings; the other '
            f'take{"s" if len(takes) > 1 else ""}:</p>' + "".join(calibration_table(t) for t in takes))

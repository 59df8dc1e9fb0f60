"""Expression fidelity on real clips (no ground truth needed): does the character do what
the actor does, and as much?

``capture2face eval fidelity`` calls :func:`evaluate_fidelity`. Per clip, six geometric
measures of the face (:data:`MEASURES`), each in inter-ocular units (IOD, landmarks
33-263 at the neutral frame); the eye openings are relative to the face's own opening at
the neutral frame instead (a character keeps its own eye size):

* **source**: the tracker's raw landmarks (``Track.landmarks_px``/``landmarks_depth``, no
  project filtering), the head rotation removed with the tracker's own transformation
  matrix, low-passed at 8 Hz (zero phase);
* **character**: the rig deformed by the animation (morphs, then skinning) at the same
  landmark vertices;
* **direct**: the simplest alternative users have, the rig's ARKit-named morphs driven
  by the tracker's raw scores (bones at rest).

Per measure: Pearson r over the tracked frames and gain = std(character) / std(source).
A measure is judged where the source moves enough to judge it (range >= 0.04 IOD; eyes
0.3 of their neutral opening): faithful when r >= 0.9 and 0.8 <= gain <= 1.25.
The ARKit curves (``Animation.arkit_weights`` when present, else the tracker's scores)
are judged against the same geometry: JawOpen vs mouth opening, EyeBlink vs eye opening
(negated), BrowInnerUp vs brow height.
The gaze (``Animation.eye_rotation``, from the irises' geometry) is judged against the
tracker's own gaze scores: each eye's yaw against its eyeLookIn/Out difference (towards
the subject's left: left eye out - in, right eye in - out), pitch against eyeLookDown -
eyeLookUp; a yaw is judged where that difference moves (std >= :data:`MIN_GAZE_STD`),
goal r >= :data:`GAZE_R_GOAL`.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError
from capture2face.rig.arkit_names import GAZE_SCORES

# name -> (landmark a, landmark b): the measure is |p_a - p_b|.
MEASURES: dict[str, tuple[int, int]] = {
    "mouth_open": (13, 14),
    "mouth_width": (61, 291),
    "brow_right": (105, 33),
    "brow_left": (334, 263),
    "eye_right": (159, 145),
    "eye_left": (386, 374),
}
EYE_MEASURES = ("eye_right", "eye_left")
IOD_PAIR = (33, 263)
LOWPASS_HZ = 8.0
MIN_RANGE_IOD = 0.04
MIN_RANGE_EYE = 0.3
R_MIN, GAIN_MIN, GAIN_MAX = 0.9, 0.8, 1.25

# ARKit curve -> (measure it is judged against, sign of the expected correlation, r goal).
# Brow height is the mean of both brows; eye opening falls as the blink rises.
ARKIT_CHECKS: dict[str, tuple[str, float, float]] = {
    "jawOpen": ("mouth_open", 1.0, 0.9),
    "eyeBlinkLeft": ("eye_left", -1.0, 0.9),
    "eyeBlinkRight": ("eye_right", -1.0, 0.9),
    "browInnerUp": ("brow", 1.0, 0.8),
}

# Gaze: name -> (eye, angle, score pair (plus, minus) whose difference it should follow):
# yaw_right, yaw_left, pitch_right, pitch_left.
GAZE_CHECKS: dict[str, tuple[int, int, tuple[str, str]]] = {
    f"{('yaw', 'pitch')[angle]}_{('right', 'left')[eye]}": (eye, angle, pair)
    for (eye, angle), pair in GAZE_SCORES.items()
}
MIN_GAZE_STD = 0.1  # std of the score difference below which the gaze barely moves
GAZE_R_GOAL = 0.8


# ---- measures ----------------------------------------------------------------------------
# The landmarks the measures use, and where each pair (and the IOD pair) sits among them.
MEASURED = sorted({i for pair in MEASURES.values() for i in pair} | set(IOD_PAIR))
_PAIRS = np.array([[MEASURED.index(a), MEASURED.index(b)] for a, b in [*MEASURES.values(), IOD_PAIR]])
CHUNK = 128  # frames per block: temporaries stay small (~8 MB) whatever the clip's length


def _distances(points: np.ndarray) -> np.ndarray:
    """(F, 7) the measured pairs' distances and the IOD of (F, len(MEASURED), 3) points."""
    return np.linalg.norm(points[:, _PAIRS[:, 0]] - points[:, _PAIRS[:, 1]], axis=-1)


def _normalise(dist: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """(F, 6) measures from (F, 7) distances and the neutral's (7,): IOD units, eyes
    relative to their own neutral opening."""
    scale = np.array([neutral[k] if name in EYE_MEASURES else neutral[-1] for k, name in enumerate(MEASURES)])
    return dist[:, :-1] / np.maximum(scale, 1e-9)


def measures_from_points(points: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """(F, 6) the :data:`MEASURES` of landmark points.

    Args:
        points: (F, L, 3) landmarks (or the rig's landmark vertices, indexed by landmark).
        neutral: (L, 3) the same face at its neutral: sets the IOD and the eyes' scale.
    """
    pts = np.asarray(points, np.float64)[:, MEASURED]
    ref = np.asarray(neutral, np.float64)[None, MEASURED]
    return _normalise(_distances(pts), _distances(ref)[0])


def lowpass(x: np.ndarray, fps: float, cutoff_hz: float = LOWPASS_HZ) -> np.ndarray:
    """Zero-phase low-pass of ``x`` (F, ...) along frames: the response of a 2nd-order
    Butterworth run forward and backward, ``1 / (1 + (f / cutoff)^4)``, applied in the
    frequency domain over an odd-reflected padding of one second (as filtfilt pads; NumPy
    only: scipy.signal costs a run more than a second to import)."""
    x = np.asarray(x, np.float64)
    if fps <= 2.0 * cutoff_hz or len(x) < 16:
        return x.copy()
    pad = min(len(x) - 1, int(round(fps)))
    widths = [(pad, pad)] + [(0, 0)] * (x.ndim - 1)
    padded = np.pad(x, widths, mode="reflect", reflect_type="odd")
    freq = np.fft.rfftfreq(len(padded), 1.0 / fps)
    response = (1.0 / (1.0 + (freq / cutoff_hz) ** 4)).reshape((-1,) + (1,) * (x.ndim - 1))
    out = np.fft.irfft(np.fft.rfft(padded, axis=0) * response, n=len(padded), axis=0)
    return out[pad:pad + len(x)]


def raw_head_landmarks(track, start: int = 0, stop: int | None = None) -> np.ndarray:
    """(F, L, 3) the tracker's unfiltered landmarks in head coordinates (cm) of frames
    ``start:stop``, from the track's raw pixel landmarks and depths, posed by MediaPipe's
    own geometry."""
    from capture2face.tracking.head_pose import head_landmarks

    stop = track.n_frames if stop is None else stop
    px = np.asarray(track.landmarks_px[start:stop], np.float64)
    depth = np.asarray(track.landmarks_depth[start:stop], np.float64)
    norm = np.concatenate([px / np.array([track.width, track.height]), depth[..., None] / track.width], -1)
    return head_landmarks(norm, track.width, track.height)[0]


def source_measures(track) -> np.ndarray:
    """(F, 6) the actor's measures: raw landmarks, head rotation removed, 8 Hz low-pass
    (computed :data:`CHUNK` frames at a time: memory stays flat on long clips)."""
    n = track.n_frames
    dist = np.concatenate([_distances(raw_head_landmarks(track, s, min(n, s + CHUNK))[:, MEASURED])
                           for s in range(0, n, CHUNK)])
    return lowpass(_normalise(dist, dist[track.neutral_frame]), track.fps)


def rig_landmark_points(rig, bone_positions: np.ndarray, blend_weights: np.ndarray,
                        landmarks=None) -> np.ndarray:
    """(F, L, 3) the rig's landmark vertices deformed (morphs, then skinning); landmarks
    without a vertex stay 0. With ``landmarks`` (K,), only those: (F, K, 3).

    Args:
        bone_positions: (F, B, 3); blend_weights: (F, M).
    """
    lv = np.asarray(rig.landmark_vertices)
    ids = np.arange(len(lv)) if landmarks is None else np.asarray(landmarks)
    rows = np.flatnonzero(lv[ids] >= 0)
    verts = lv[ids[rows]]
    weights = np.asarray(blend_weights, np.float64)
    pos = rig.vertices[verts].astype(np.float64) + np.einsum(
        "fm,mvc->fvc", weights, rig.morph_positions[:, verts].astype(np.float64))
    skin = rig.dense_skin_weights()[verts].astype(np.float64)  # (n, B)
    pos += np.einsum("vb,fbc->fvc", skin, np.asarray(bone_positions, np.float64) - rig.bone_rest)
    out = np.zeros((len(pos), len(ids), 3))
    out[:, rows] = pos
    return out


def character_measures(rig, bone_positions: np.ndarray, blend_weights: np.ndarray) -> np.ndarray:
    """(F, 6) the character's measures (its own rest pose is its neutral)."""
    if np.any(np.asarray(rig.landmark_vertices)[MEASURED] < 0):
        raise CaptureError(f"character '{rig.name}' has no vertex for some measured landmarks")
    rest = _distances(rig_landmark_points(rig, rig.bone_rest[None], np.zeros((1, rig.n_morphs)), MEASURED))[0]
    n = len(bone_positions)
    dist = np.concatenate([
        _distances(rig_landmark_points(rig, bone_positions[s:s + CHUNK], blend_weights[s:s + CHUNK], MEASURED))
        for s in range(0, n, CHUNK)])
    return _normalise(dist, rest)


def direct_weights(rig, scores: np.ndarray, names: list[str]) -> np.ndarray:
    """(F, M) the rig's morphs driven by the tracker's scores of the same (ARKit) name."""
    index = {n.lower(): i for i, n in enumerate(names)}
    out = np.zeros((len(scores), rig.n_morphs), np.float32)
    for m, name in enumerate(rig.morph_names):
        if name.lower() in index:
            out[:, m] = np.clip(scores[:, index[name.lower()]], 0.0, 1.0)
    return out


# ---- figures -----------------------------------------------------------------------------
def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson r of two series; 0 when either is constant (a constant explains nothing)."""
    a = np.asarray(a, np.float64) - np.mean(a)
    b = np.asarray(b, np.float64) - np.mean(b)
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 1e-12 else 0.0


def compare(source: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """(r, gain) of one measure over frames."""
    s_std = float(np.std(source))
    return pearson(source, other), (float(np.std(other)) / s_std if s_std > 1e-12 else 0.0)


def faithful(r: float, gain: float) -> bool:
    return r >= R_MIN and GAIN_MIN <= gain <= GAIN_MAX


@dataclass
class ClipFidelity:
    """One clip's measures over its tracked frames (T of them).

    Attributes:
        name: clip name.
        times: (T,) seconds.
        source, character, direct: (T, 6) the measures (see module doc).
        arkit: (T, A) ARKit curves judged, names in ``arkit_names``.
        arkit_source: which curves were judged ("animation" or "tracker").
        gaze: (T, 2, 2) the animation's eye yaw and pitch (degrees), or None.
        gaze_scores: (T, 4) the tracker's score differences of :data:`GAZE_CHECKS`.
    """

    name: str
    times: np.ndarray
    source: np.ndarray
    character: np.ndarray
    direct: np.ndarray
    arkit: np.ndarray
    arkit_names: list[str]
    arkit_source: str
    gaze: np.ndarray | None = None
    gaze_scores: np.ndarray | None = None

    def figures(self) -> dict:
        """Per measure r, gain, source range, judged and faithful for the character and
        the direct alternative; ARKit curve correlations; a summary."""
        out: dict = {"clip": self.name, "frames": int(len(self.times)), "measures": {}, "arkit": {}}
        judged = passed = beats = 0
        for k, name in enumerate(MEASURES):
            src = self.source[:, k]
            rng = float(src.max() - src.min()) if len(src) else 0.0
            limit = MIN_RANGE_EYE if name in EYE_MEASURES else MIN_RANGE_IOD
            r, g = compare(src, self.character[:, k])
            dr, dg = compare(src, self.direct[:, k])
            ok = faithful(r, g)
            entry = {"range": round(rng, 4), "judged": rng >= limit, "r": round(r, 3), "gain": round(g, 3),
                     "faithful": ok, "direct_r": round(dr, 3), "direct_gain": round(dg, 3),
                     "direct_faithful": faithful(dr, dg)}
            out["measures"][name] = entry
            if entry["judged"]:
                judged += 1
                passed += ok
                # Not worse than direct: r at least as high, or a gain at least as close to 1
                # (in log terms); worse means behind it on both.
                beats += r >= dr - 1e-3 or abs(np.log(max(g, 1e-6))) <= abs(np.log(max(dg, 1e-6)))
        brow = self.source[:, [list(MEASURES).index("brow_right"), list(MEASURES).index("brow_left")]].mean(1)
        for name, (measure, sign, goal) in ARKIT_CHECKS.items():
            if name not in self.arkit_names:
                continue
            geo = brow if measure == "brow" else self.source[:, list(MEASURES).index(measure)]
            curve = self.arkit[:, self.arkit_names.index(name)]
            r = sign * pearson(geo, curve)
            out["arkit"][name] = {"against": measure, "r": round(r, 3), "goal": goal, "max": round(float(curve.max()), 3),
                                  "met": bool(r >= goal)}
        out["arkit_source"] = self.arkit_source
        if self.gaze is not None and self.gaze_scores is not None:
            out["gaze"] = {}
            for k, (name, (eye, angle, _)) in enumerate(GAZE_CHECKS.items()):
                score = self.gaze_scores[:, k]
                spread = float(score.std()) if len(score) else 0.0
                r = pearson(self.gaze[:, eye, angle], score)
                entry = {"r": round(r, 3), "score_std": round(spread, 3),
                         "judged": bool(name.startswith("yaw") and spread >= MIN_GAZE_STD)}
                if entry["judged"]:
                    entry.update(goal=GAZE_R_GOAL, met=bool(r >= GAZE_R_GOAL))
                out["gaze"][name] = entry
        out["summary"] = {"judged": judged, "faithful": int(passed), "not_worse_than_direct": int(beats)}
        return out


def clip_fidelity(track, animation, rig, name: str = "") -> ClipFidelity:
    """The measures of one retargeted clip (its ``Track``, ``Animation`` and character)."""
    keep = np.asarray(track.presence, bool)
    source = source_measures(track)
    character = character_measures(rig, animation.bone_positions, animation.blend_weights)
    scores = np.asarray(track.blendshapes)
    rest = np.broadcast_to(rig.bone_rest[None], (len(scores),) + rig.bone_rest.shape)  # a view, no copy
    direct = character_measures(rig, rest, direct_weights(rig, scores, track.blendshape_names))
    if getattr(animation, "arkit_weights", None) is not None:
        arkit, names, which = np.asarray(animation.arkit_weights), list(animation.arkit_names), "animation"
    else:
        arkit, names, which = scores, list(track.blendshape_names), "tracker"
    gaze = gaze_scores = None
    if getattr(animation, "eye_rotation", None) is not None:
        col = {n: i for i, n in enumerate(track.blendshape_names)}
        if all(a in col and b in col for _, _, (a, b) in GAZE_CHECKS.values()):
            gaze = np.asarray(animation.eye_rotation, np.float64)[keep]
            gaze_scores = np.stack([scores[:, col[a]].astype(np.float64) - scores[:, col[b]]
                                    for _, _, (a, b) in GAZE_CHECKS.values()], 1)[keep]
    return ClipFidelity(name=name or Path(str(track.source)).stem, times=np.asarray(track.times)[keep],
                        source=source[keep], character=character[keep], direct=direct[keep],
                        arkit=np.asarray(arkit[keep], np.float64), arkit_names=names, arkit_source=which,
                        gaze=gaze, gaze_scores=gaze_scores)


# ---- clips and run folders -----------------------------------------------------------------
def _load_run(folder: Path):
    from capture2face.pipeline import load_character
    from capture2face.retarget.animation import Animation
    from capture2face.tracking.track import Track

    missing = [f for f in ("track.npz", "animation.npz") if not (folder / f).is_file()]
    if missing:
        raise CaptureError(f"{folder}: not a run folder (no {', '.join(missing)})")
    track, animation = Track.load(folder / "track.npz"), Animation.load(folder / "animation.npz")
    character = None
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
        character = report.get("options", {}).get("character")
    except (OSError, ValueError):
        pass
    return track, animation, load_character(character)


def fidelity_of(path: str | os.PathLike, character=None, progress: bool = False) -> ClipFidelity:
    """A clip (tracked and retargeted here, nothing rendered) or a ``run`` output folder."""
    from capture2face.pipeline import RunOptions, load_character, retarget_stage, track_stage

    path = Path(path)
    if path.is_dir():
        track, animation, rig = _load_run(path)
        return clip_fidelity(track, animation, rig, path.name)
    rig = load_character(character)
    with tempfile.TemporaryDirectory(prefix="capture2face-fidelity-") as work:
        track = track_stage(path, RunOptions(), progress=progress, workdir=work)
        animation = retarget_stage(track, rig)
        return clip_fidelity(track, animation, rig, path.stem)


def summary_line(results: list[dict]) -> str:
    judged = sum(r["summary"]["judged"] for r in results)
    ok = sum(r["summary"]["faithful"] for r in results)
    beats = sum(r["summary"]["not_worse_than_direct"] for r in results)
    arkit = [a for r in results for a in r["arkit"].values()]
    gaze = [g for r in results for g in r.get("gaze", {}).values() if g["judged"]]
    return (f"{len(results)} clips: {ok}/{judged} judged measures faithful (r >= {R_MIN}, gain "
            f"{GAIN_MIN}-{GAIN_MAX}), {beats}/{judged} not worse than the direct scores; "
            f"ARKit curves {sum(a['met'] for a in arkit)}/{len(arkit)} meet their r goal"
            + (f"; eye yaw {sum(g['met'] for g in gaze)}/{len(gaze)} follows eyeLookIn/Out (r >= {GAZE_R_GOAL})"
               if gaze else ""))


def table(results: list[dict]) -> str:
    """A plain-text (Markdown) table: clip x measure, ``r / gain`` (direct in brackets)."""
    head = "| clip | " + " | ".join(MEASURES) + " |"
    lines = [head, "|" + "---|" * (len(MEASURES) + 1)]
    for res in results:
        cells = []
        for name in MEASURES:
            m = res["measures"][name]
            mark = "" if not m["judged"] else (" ✓" if m["faithful"] else " ✗")
            cells.append(f"{m['r']:.2f} / {m['gain']:.2f}{mark} ({m['direct_r']:.2f} / {m['direct_gain']:.2f})"
                         if m["judged"] else f"— ({m['range']:.3f})")
        lines.append(f"| {res['clip']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ---- picture ------------------------------------------------------------------------------
def plot(fid: ClipFidelity, path: str | os.PathLike, width: int = 960, row: int = 110) -> None:
    """A PNG: each measure over time, source (white), character (orange), direct (blue)."""
    import cv2

    from capture2face.io.atomic import atomic_path

    names = list(MEASURES)
    img = np.full((row * len(names) + 30, width, 3), 24, np.uint8)
    x0, x1 = 120, width - 10
    n = len(fid.times)
    xs = x0 + (np.arange(n) / max(1, n - 1)) * (x1 - x0)
    colours = {"source": (235, 235, 235), "character": (40, 150, 255), "direct": (230, 140, 60)}  # BGR
    for k, name in enumerate(names):
        top = 10 + k * row
        series = {"source": fid.source[:, k], "character": fid.character[:, k], "direct": fid.direct[:, k]}
        lo = min(float(s.min()) for s in series.values()) if n else 0.0
        hi = max(float(s.max()) for s in series.values()) if n else 1.0
        span = max(hi - lo, 1e-6)
        cv2.rectangle(img, (x0, top), (x1, top + row - 14), (60, 60, 60), 1)
        cv2.putText(img, name, (8, top + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (220, 220, 220), 1, cv2.LINE_AA)
        cv2.putText(img, f"{hi:.3f}", (8, top + 40), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (150, 150, 150), 1, cv2.LINE_AA)
        cv2.putText(img, f"{lo:.3f}", (8, top + row - 18), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (150, 150, 150), 1,
                    cv2.LINE_AA)
        for label, values in series.items():
            ys = top + (row - 16) - (values - lo) / span * (row - 20)
            pts = np.stack([xs, ys], 1).round().astype(np.int32)
            cv2.polylines(img, [pts], False, colours[label], 1, cv2.LINE_AA)
    legend_y = img.shape[0] - 8
    for i, (label, colour) in enumerate(colours.items()):
        cv2.putText(img, label, (x0 + 110 * i, legend_y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    path = Path(path)
    with atomic_path(path) as tmp:  # keeps the .png suffix OpenCV picks the format from
        if not cv2.imwrite(str(tmp), img):
            raise CaptureError(f"{path}: cannot write the picture")


def evaluate_fidelity(paths: list[str | os.PathLike], character=None, plot_dir: str | os.PathLike | None = None,
                      progress: bool = False) -> dict:
    """Fidelity figures of clips or run folders: ``{"clips": [...], "summary": line}``.

    With ``plot_dir``, one ``<clip>.fidelity.png`` per clip is written there.
    """
    results = []
    for p in paths:
        fid = fidelity_of(p, character, progress)
        res = fid.figures()
        if plot_dir is not None:
            Path(plot_dir).mkdir(parents=True, exist_ok=True)
            picture = Path(plot_dir) / f"{fid.name}.fidelity.png"
            plot(fid, picture)
            res["picture"] = os.fspath(picture)
        results.append(res)
    return {"clips": results, "summary": summary_line(results)}

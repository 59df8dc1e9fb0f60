"""``capture2face eval characters``: a gallery of characters performing one real clip.

The clip is tracked once; each character is then retargeted, rendered (avatar.mp4) and
exported into ``DIR/<name>/`` (a ``run`` folder without compare.mp4 and report), and gets

* a contact sheet ``DIR/<name>.png``: the actor (a crop of the source frame) above the
  character at rest and at the clip's peaks of jawOpen, browInnerUp, eyeBlink,
  mouthSmile and browDown (the clip's ARKit curves, ``Animation.arkit_weights``); then
  frontal close-ups of the forehead, the glabella and an eye's outer corner (wrinkles),
  each beside the actor's, at the clip's largest brow raise, frown and squint; then the
  same close-ups at rest and at full influence (the character's reference pose,
  ``stretch`` for the forehead, ``compress`` for the others);
* the figures of the issue's goals: landmark fidelity (judged measures faithful, as
  ``eval fidelity``) and the video tracked back (``eval shading``: mouth, brows and eyes
  r and gain, skin darkening p95); and the same tracked back from a check render with the
  character's hair hidden (``shading_hair_hidden``, :mod:`capture2face.eval.hair_hidden`:
  a fringe over the brows hides them from the tracker, not from the viewer). The darkening
  is read in skin.mp4, the same frames drawn again with the base colour one flat tone
  (:data:`FLAT_SKIN`), so that a beard or painted shadow sliding under a disc is not taken
  for a shading fault. ``darkening_cause`` says where and when it comes from: the darkest
  disc, its darkest frames, and the morphs and ARKit curves then.

A character that cannot be loaded or driven gets a row with its one-line refusal; one
that fails later gets its error; neither stops the others.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture2face.camera import face_centre_and_height
from capture2face.character.landmark_sources import MORPHS
from capture2face.errors import CaptureError
from capture2face.eval import shading
from capture2face.eval.contact_sheet import Cell, draw_sheet, square_crop, write_image
from capture2face.eval.hair_hidden import hair_hidden_figures
from capture2face.eval.posed import MEASURE as POSED
from capture2face.eval.posed import posed_follow
from capture2face.io.video_input import iter_frames
from capture2face.io.video_output import VideoWriter
from capture2face.measures import clip_fidelity
from capture2face.pipeline import RenderPass, RunOptions, export_stage, retarget_stage, track_stage
from capture2face.pipeline.preflight import check_character
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.topology import IOD_PAIR
from capture2face.tracking.track import Track

REPO = Path(__file__).resolve().parents[2]
# d12: a wide-open mouth, brow raises, smiles and blinks in 183 frames (the close-ups at full
# influence show the frown's wrinkles it lacks).
DEFAULT_CLIPS = (REPO.parent / "shared" / "clips" / "d12.mp4", REPO / "sample_videos" / "sample.mp4")

#: Sheet columns: label -> the ARKit curves whose mean peaks there (None: the actor's rest).
EXPRESSIONS: dict[str, tuple[str, ...] | None] = {
    "rest": None,
    "jawOpen": ("jawOpen",),
    "browInnerUp": ("browInnerUp",),
    "eyeBlink": ("eyeBlinkLeft", "eyeBlinkRight"),
    "mouthSmile": ("mouthSmileLeft", "mouthSmileRight"),
    "browDown": ("browDownLeft", "browDownRight"),
}
#: Close-ups: label -> (curves whose peak frame, landmarks whose mean is the centre, width in
#: inter-ocular distances, the centre's place as a fraction of the face's height from its
#: centre where the character has no landmarks, the reference pose of full influence).
CLOSE_UPS = {
    "forehead": (("browInnerUp",), (151, 9), 1.3, (0.0, 0.33), "stretch"),
    "glabella": (("browDownLeft", "browDownRight"), (9, 168), 0.75, (0.0, 0.2), "compress"),
    "eye corner": (("eyeSquintRight", "mouthSmileRight", "cheekSquintRight"), (33,), 0.7, (-0.2, 0.12),
                   "compress"),
}


#: Issue 31's goals, tracked back from avatar.mp4: feature -> (r at least, gain at least);
#: skin darkening p95 at most DARKENING_GOAL; landmark fidelity FIDELITY_GOAL of the judged.
FOLLOW_GOALS = {"mouth_open": (0.85, 0.7), "eyes": (0.8, 0.7), "brows": (0.75, 0.6)}
DARKENING_GOAL = 0.03
TRACKED = "tracked back"  # row["follow_by"]: the figures the goals judge (or POSED)
FIDELITY_GOAL = 0.9
NO_MOTION = 0.05  # a feature whose morphs move it under this share of the avatar's range is not judged
#: sRGB base colour of every character in skin.mp4 (where the darkening is read): one mid skin
#: tone for all, near the built-in avatar's (215 165 144): the tone curve darkens a dark skin more
#: for the same shading (Rocketbox 4.5 % in its own tone, 1.9 % in this).
FLAT_SKIN = (200, 160, 140)


def default_clip() -> Path:
    """../shared/clips/d12.mp4 beside the repository when present, else the sample clip."""
    return next((p for p in DEFAULT_CLIPS if p.is_file()), DEFAULT_CLIPS[-1])


def character_name(spec) -> str:
    return "default" if spec is None else Path(os.fspath(spec)).stem


# ---- frames ---------------------------------------------------------------------------------
def peak_frame(animation, track, curves: tuple[str, ...] | None) -> tuple[int, float]:
    """(frame, value) where the mean of ``curves`` peaks among the frames with a face
    (``curves`` None: the actor's rest frame, value 0)."""
    if curves is None or animation.arkit_weights is None:
        return int(track.neutral_frame), 0.0
    names = list(animation.arkit_names)
    cols = [names.index(c) for c in curves if c in names]
    values = np.asarray(animation.arkit_weights, np.float64)[:, cols].mean(1) if cols else \
        np.zeros(animation.n_frames)
    values = np.where(np.asarray(track.presence[:len(values)], bool), values, -1.0)
    f = int(np.argmax(values))
    return f, float(values[f])


def chosen_frames(animation, track) -> dict[str, tuple[int, float]]:
    """Label -> (frame, curve value) of every sheet column and close-up."""
    out = {label: peak_frame(animation, track, curves) for label, curves in EXPRESSIONS.items()}
    out.update({label: peak_frame(animation, track, spec[0]) for label, spec in CLOSE_UPS.items()})
    return out


def source_frames(clip, frames: set[int]) -> dict[int, np.ndarray]:
    """The clip's RGB frames of the indices ``frames``."""
    out = {}
    for f, (_, rgb) in enumerate(iter_frames(clip, max_frames=max(frames) + 1)):
        if f in frames:
            out[f] = rgb
    return out


def actor_crop(rgb: np.ndarray, px: np.ndarray, landmarks=None, width_iod: float | None = None) -> np.ndarray:
    """The actor's face (``landmarks`` None: the landmarks' box, with a margin) or the square
    ``width_iod`` inter-ocular distances wide about the mean of ``landmarks``."""
    px = np.asarray(px, np.float64)
    if landmarks is None:
        lo, hi = px.min(0), px.max(0)
        return square_crop(rgb, (lo + hi) / 2, 0.6 * (hi - lo).max())
    iod = np.linalg.norm(px[IOD_PAIR[0]] - px[IOD_PAIR[1]])
    return square_crop(rgb, px[list(landmarks)].mean(0), width_iod * iod / 2)


# ---- close-ups ------------------------------------------------------------------------------
def close_up_target(rig: FaceRig, label: str) -> tuple[np.ndarray, float]:
    """(centre (3,) head cm, width cm) of close-up ``label`` on the character at rest."""
    _, landmarks, width_iod, fallback, _ = CLOSE_UPS[label]
    ids = list(landmarks) + list(IOD_PAIR)
    if np.all(np.asarray(rig.landmark_vertices)[ids] >= 0):
        points = landmark_points(rig, rig.vertices, ids).astype(np.float64)
        iod = float(np.linalg.norm(points[-1] - points[-2]))
        return points[:len(landmarks)].mean(0), width_iod * iod
    centre, height = face_centre_and_height(rig)
    return centre + np.array([fallback[0] * height, fallback[1] * height, 0.0]), 0.5 * width_iod * height


def close_up_state(rig: FaceRig, state, label: str, fov_y_degrees: float):
    """``state`` seen from the front, the camera moved so that close-up ``label`` fills the
    frame (the head joint, if any, turned back to rest)."""
    centre, width = close_up_target(rig, label)
    distance = width / (2.0 * np.tan(np.radians(fov_y_degrees) / 2.0))
    pose = np.eye(4, dtype=np.float32)
    pose[:3, 3] = np.array([0.0, 0.0, -distance]) - centre
    turn = None if state.head_rotation is None else np.eye(3, dtype=np.float32)
    return dataclasses.replace(state, head_pose=pose, head_rotation=turn)


# ---- one character --------------------------------------------------------------------------
def _fidelity(track, animation, rig: FaceRig, name: str) -> dict:
    try:
        summary = clip_fidelity(track, animation, rig, name).figures()["summary"]
    except CaptureError as exc:
        return {"judged": 0, "faithful": 0, "note": str(exc)}
    return {"judged": int(summary["judged"]), "faithful": int(summary["faithful"])}


def _posed(track, animation, rig: FaceRig) -> dict | None:
    """The posed-landmark figures (:mod:`.posed`); None without the measured landmarks."""
    try:
        return posed_follow(track, animation, rig)
    except CaptureError:
        return None


def _render(clip, track, animation, rig: FaceRig, folder: Path, options: RunOptions, frames: dict,
            progress: bool) -> tuple[dict, dict]:
    """avatar.mp4 into ``folder``; (the kept frames, the close-ups) as RGB images. The
    close-ups: ``label`` at the clip's frame, ``(label, "rest")`` and ``(label, "full")``."""
    render_pass = RenderPass(clip, track, animation, rig, folder, options,
                             keep_frames=[f for f, _ in frames.values()])
    kept = render_pass.run(progress)["kept"]
    skin_video(render_pass, folder / "skin.mp4")
    fov = render_pass.render_options.fov_y_degrees
    front = np.eye(4)
    close = {}
    with Renderer.create_from_options(rig, render_pass.render_options) as renderer:
        for label, spec in CLOSE_UPS.items():
            states = {label: render_pass.frame_state(frames[label][0]), (label, "rest"): FrameState.at_pose(rig, front),
                      (label, "full"): FrameState.at_pose(rig, front, spec[4] if spec[4] in rig.pose_names else None)}
            for key, state in states.items():
                close[key] = renderer.render(close_up_state(rig, state, label, fov))
    return kept, close


def skin_video(render_pass: RenderPass, path: Path) -> Path:
    """``render_pass``'s frames drawn again with the base colour :data:`FLAT_SKIN` everywhere
    (alpha, normal and wrinkle maps kept): the shading alone, as H.264 like avatar.mp4."""
    rig, options = render_pass.rig, render_pass.options
    flat = rig.replace(albedo=np.broadcast_to(np.asarray(FLAT_SKIN, np.uint8), rig.albedo.shape).copy())
    with Renderer.create_from_options(flat, render_pass.render_options) as renderer, \
            VideoWriter(path, render_pass.fps, render_pass.render_options.width_height, crf=options.crf,
                        preset=options.preset, times=render_pass.times) as out:
        for i in range(render_pass.n):
            out.write(renderer.render(render_pass.frame_state(i)))
    return path


def perform(spec, clip, track: Track, out_dir: Path, size: int, cell: int, progress: bool = False) -> dict:
    """One character's row: run folder ``out_dir/<name>/``, sheet ``out_dir/<name>.png``,
    figures. Raises CaptureError when it cannot be loaded or driven."""
    t0 = time.perf_counter()
    rig = check_character(spec)
    name = character_name(spec)
    folder = out_dir / name
    folder.mkdir(parents=True, exist_ok=True)
    options = RunOptions(character=spec, render=RenderOptions(size=size), compare=False, audio=False)
    animation = retarget_stage(track, rig, options.retarget)
    track.save(folder / "track.npz")
    frames = chosen_frames(animation, track)
    kept, close = _render(clip, track, animation, rig, folder, options, frames, progress)
    export_stage(rig, animation, folder, track, character=spec)
    row = {"landmarks": int(np.count_nonzero(np.asarray(rig.landmark_vertices) >= 0)),
           "fidelity": _fidelity(track, animation, rig, name)}
    row["shading"] = shading.shading_of(folder, progress=progress, skin_video=folder / "skin.mp4")
    row["darkening_cause"] = darkening_cause(animation, row["shading"])
    row["posed"] = _posed(track, animation, rig)
    # A face the tracker could not read (its landmarks from its morphs) cannot be tracked back.
    row["follow_by"] = POSED if rig.landmark_source == MORPHS and row["posed"] else TRACKED
    row["shading_hair_hidden"] = hair_hidden_figures(clip, track, animation, rig, folder, options, row["shading"],
                                                     progress)
    row["goals"] = goals_met(row)
    sheet = draw_sheet(_sheet_rows(clip, track, frames, kept, close), cell, _title(name, clip, row))
    row["sheet"] = os.fspath(out_dir / f"{name}.png")
    write_image(sheet, row["sheet"])
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return row


def darkening_cause(animation, figures: dict, top: int = 6) -> dict:
    """Where and when the darkening comes from: the disc with the highest p95 in
    ``figures`` (:func:`~.shading.shading_of`), its darkest frames, and over those frames the
    mean weight of the ``top`` most-weighted morphs beside the clip's ARKit curves (what
    the solve set against what the actor showed)."""
    disc = max(figures["darkening_p95"], key=figures["darkening_p95"].get)
    frames = [f for f, _ in figures["darkening_frames"][disc]]
    out = {"disc": disc, "frames": frames, "morphs": {}, "curves": {}}
    for key, names, weights in (("morphs", animation.blend_names, animation.blend_weights),
                                ("curves", animation.arkit_names, animation.arkit_weights)):
        if weights is None or not frames or not len(names):
            continue
        mean = np.asarray(weights, np.float64)[frames].mean(0)
        out[key] = {names[k]: round(float(mean[k]), 3) for k in np.argsort(-mean, kind="stable")[:top] if mean[k] > 0}
    return out


def goals_met(row: dict) -> dict[str, bool]:
    """Which of the goals (:data:`FOLLOW_GOALS`, :data:`DARKENING_GOAL`,
    :data:`FIDELITY_GOAL`) a character's figures meet (fidelity: only where judged). The
    mouth, eyes and brows are judged on ``row["follow_by"]``'s figures: tracked back (the
    default), or the posed landmarks (r, and the gain in the character's range) where the
    tracker cannot read the face; a feature none of its morphs moves is not judged (a
    visemes-only head's brows and eyes), nor the darkening where the tracker cannot read
    the face (its discs would lie where it guesses)."""
    sh, fid = row["shading"], row["fidelity"]
    tracked = row.get("follow_by", TRACKED) == TRACKED
    out = {}
    for k, (r, g) in FOLLOW_GOALS.items():
        got_r, got_gain = follow_figures(row, k)
        if moves(row, k) and (np.isfinite(got_r) or tracked):
            out[k] = bool(got_r >= r and got_gain >= g)
    if tracked:
        out["darkening"] = bool(sh["darkening_p95_mean"] <= DARKENING_GOAL)
    if fid["judged"]:
        out["fidelity"] = bool(fid["faithful"] >= FIDELITY_GOAL * fid["judged"])
    return out


def moves(row: dict, feature: str) -> bool:
    """False where none of the character's morphs moves ``feature``: its posed range under
    :data:`NO_MOTION` of the built-in avatar's (a viseme grazes the brows by 0.0002)."""
    posed = row.get("posed") or {}
    return posed.get(f"{feature}_range", 1.0) >= NO_MOTION


def follow_figures(row: dict, feature: str) -> tuple[float, float]:
    """(r, gain) of ``feature`` ("mouth_open", "brows", "eyes") the goals judge."""
    if row.get("follow_by", TRACKED) == POSED:
        return row["posed"][f"{feature}_r"], row["posed"][f"{feature}_range_gain"]
    return row["shading"][f"{feature}_r"], row["shading"][f"{feature}_gain"]


def _sheet_rows(clip, track: Track, frames: dict, kept: dict, close: dict) -> list[list[Cell]]:
    source = source_frames(clip, {f for f, _ in frames.values()})
    actor, character = [], []
    for label in EXPRESSIONS:
        f, value = frames[label]
        actor.append(Cell(actor_crop(source[f], track.landmarks_px[f]), f"actor f{f}"))
        character.append(Cell(kept.get(f), label if label == "rest" else f"{label} {value:.2f}"))
    closes, full = [], []
    for label, (_, landmarks, width_iod, _, pose) in CLOSE_UPS.items():
        f, value = frames[label]
        closes.append(Cell(actor_crop(source[f], track.landmarks_px[f], landmarks, width_iod), f"actor f{f}"))
        closes.append(Cell(close[label], f"{label} {value:.2f}"))
        full.append(Cell(close[(label, "rest")], f"{label} at rest"))
        full.append(Cell(close[(label, "full")], f"{label} full {pose}"))
    return [actor, character, closes, full]


def _title(name: str, clip, row: dict) -> list[str]:
    fid, sh, bare = row["fidelity"], row["shading"], row["shading_hair_hidden"]
    by = row.get("follow_by", TRACKED)
    parts = []
    for label, k in (("mouth", "mouth_open"), ("brows", "brows"), ("eyes", "eyes")):
        r, g = follow_figures(row, k)
        parts.append(f"{label} r {r:.2f} g {g:.2f}" if np.isfinite(r) and moves(row, k)
                     else f"{label}: no morph moves them")
    figures = ", ".join(parts)
    return [f"{name} on {Path(clip).name}: landmarks {row['landmarks']}, fidelity {fid['faithful']}/{fid['judged']}",
            f"{by}: {figures}, dark {sh['darkening_p95_mean']:.1%}; hair hidden: brows r {bare['brows_r']:.2f} "
            f"g {bare['brows_gain']:.2f}, eyes r {bare['eyes_r']:.2f} g {bare['eyes_gain']:.2f}"]


# ---- the gallery ----------------------------------------------------------------------------
def evaluate_characters(characters: list, clip=None, out_dir: str | os.PathLike = "gallery", size: int = 256,
                        cell: int = 192, track_file=None, progress: bool = False) -> dict:
    """Every character of ``characters`` (None: the default avatar) performing ``clip``
    (None: :func:`default_clip`): ``{"clip", "characters": [rows], "summary"}``.

    Args:
        track_file: the clip's track.npz (tracked before) instead of tracking it here.
    """
    clip = Path(clip) if clip is not None else default_clip()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="capture2face-characters-") as work:
        track = Track.load(track_file) if track_file else \
            track_stage(clip, RunOptions(), progress=progress, workdir=work)
        for spec in tqdm(characters or [None], desc="characters", unit="character", disable=not progress):
            row = {"character": "default" if spec is None else os.fspath(spec), "name": character_name(spec)}
            try:
                row.update(status="ok", **perform(spec, clip, track, out, size, cell, progress))
            except CaptureError as exc:
                row.update(status="refused", message=str(exc))
            except Exception as exc:  # one bad file never stops the others (as batch)
                row.update(status="failed", message=f"{type(exc).__name__}: {exc}")
            rows.append(row)
    return {"clip": os.fspath(clip), "characters": rows, "summary": summary_line(rows)}


def summary_line(rows: list[dict]) -> str:
    ok = [r for r in rows if r["status"] == "ok"]
    refused = sum(r["status"] == "refused" for r in rows)
    met = sum(all(r["goals"].values()) for r in ok)
    return (f"{len(rows)} characters: {len(ok)} performed ({met} meet every goal: mouth r >= "
            f"{FOLLOW_GOALS['mouth_open'][0]} gain >= {FOLLOW_GOALS['mouth_open'][1]}, eyes r >= "
            f"{FOLLOW_GOALS['eyes'][0]} gain >= {FOLLOW_GOALS['eyes'][1]}, brows r >= {FOLLOW_GOALS['brows'][0]} "
            f"gain >= {FOLLOW_GOALS['brows'][1]}, darkening p95 <= {DARKENING_GOAL:.0%}, fidelity >= "
            f"{FIDELITY_GOAL:.0%}), {refused} refused, {len(rows) - len(ok) - refused} failed")


def _mark(met: bool | None) -> str:
    return "" if met is None else (" ✓" if met else " ✗")


def table(rows: list[dict]) -> str:
    """A Markdown table, one row per character (✓ / ✗: the goal met or not)."""
    lines = ["| character | landmarks | fidelity | mouth r / gain | brows r / gain | eyes r / gain | darkening p95 "
             "| hair hidden: brows / eyes |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['name']} | {r['status']}: {r['message']} | | | | | | |")
            continue
        fid, sh, met = r["fidelity"], r["shading"], r["goals"]
        cells = [str(r["landmarks"]), f"{fid['faithful']}/{fid['judged']}{_mark(met.get('fidelity'))}"]
        for k in ("mouth_open", "brows", "eyes"):
            r_, g_ = follow_figures(r, k)
            by = " (posed)" if r.get("follow_by") == POSED else ""
            cells.append(f"{r_:.2f} / {g_:.2f}{by}{_mark(met.get(k))}" if np.isfinite(r_) and moves(r, k)
                         else "no morph moves it")
        dark = f"{sh['darkening_p95_mean']:.1%}"
        cells.append(f"{dark}{_mark(met['darkening'])}" if "darkening" in met else f"({dark})")
        bare = r["shading_hair_hidden"]
        cells.append(" / ".join(f"{bare[k + '_r']:.2f} / {bare[k + '_gain']:.2f}" for k in ("brows", "eyes")))
        lines.append(f"| {r['name']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)

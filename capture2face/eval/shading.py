"""``capture2face eval shading``: does a rendered character shade right and perform what the
actor performs? Judged on the output video alone, the way a viewer sees it.

A ``run`` folder's avatar.mp4 is tracked with the clips' tracker; in every frame with a
face, the skin's brightness is sampled in discs on the cheeks and the chin (landmark
positions in the video). A shading fault (normals turned by combined morphs) darkens the
discs as the face moves. The head turning under the light also lights a disc differently
(a cheek turned away darkens by 5-10 %): a rigid patch's diffuse light is linear in the
head rotation's nine entries, so that part (a least-squares fit over the frames) is taken
out first. The figure is each disc's 95th percentile of what is left darkening,
``max(0, 1 - brightness / its median frame)`` (one-sided: a fault darkens), judged on the
mean over the discs. The mouth opening measured in that tracked video
(:func:`~capture2face.measures.source_measures`) is compared with the source clip's (the
run's track.npz): a character whose mouth does not open on screen fails it whatever its
animation says. The brows (the two brow heights' mean) and the eyes (the two lid
openings' mean) are compared the same way (r, and gain: the character's standard
deviation over the actor's), reported beside the mouth.

Given a second video of the same frames with the character's base colour one flat tone
(``eval characters`` draws it, skin.mp4), the darkening is read there instead, in the
discs found in avatar.mp4: a tracked landmark slides a little over the character's
surface as the face moves, and on a textured head the disc then takes in more or less of
a beard, a goatee or painted-in shadow (Ready Player Me's goatee: the chin's figure 11 %
in avatar.mp4, 1.8 % with the colour flat), which is no shading fault. avatar.mp4's own
figure is kept beside it (``darkening_p95_mean_avatar``). ``darkening_frames`` names each
disc's darkest frames (where and when its p95 comes from).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError
from capture2face.io.video_input import iter_frames
from capture2face.maths.rotations import rotation_part
from capture2face.measures import BROW_COLUMNS, EYE_MEASURES, MEASURES, compare, source_measures
from capture2face.pipeline import RunOptions, track_stage
from capture2face.topology import IOD_PAIR
from capture2face.tracking.track import Track

# Disc centres (MediaPipe landmarks) and their radius in inter-ocular distances.
PATCHES = {"cheek_right": 205, "cheek_left": 425, "chin": 199}
PATCH_RADIUS_IOD = 0.08
BRIGHTNESS_GOAL = 0.03  # p95 darkening from the disc's median frame, mean over the discs
MOUTH_R_GOAL = 0.85
DARKEST_FRAMES = 8  # frames named per disc in the figures: its p95 is read among them (1 in 20 frames)
#: What the tracked-back video is compared on: name -> the measure columns averaged.
FEATURES = {"mouth_open": [list(MEASURES).index("mouth_open")], "brows": BROW_COLUMNS,
            "eyes": [list(MEASURES).index(e) for e in EYE_MEASURES]}


def _luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float32) @ np.array([0.2126, 0.7152, 0.0722], np.float32)


def patch_brightness(video: str | os.PathLike, track: Track) -> np.ndarray:
    """(F, P) mean luminance (0-255) of each of :data:`PATCHES` in each frame of ``video``
    (NaN where ``track`` has no face)."""
    names = list(PATCHES.values())
    out = np.full((track.n_frames, len(names)), np.nan, np.float32)
    for f, (_, rgb) in enumerate(iter_frames(video, max_frames=track.n_frames)):
        if not track.presence[f]:
            continue
        px = np.asarray(track.landmarks_px[f], np.float64)
        radius = PATCH_RADIUS_IOD * np.linalg.norm(px[IOD_PAIR[0]] - px[IOD_PAIR[1]])
        for k, lm in enumerate(names):
            out[f, k] = _disc_mean(rgb, px[lm], radius)
    return out


def _disc_mean(rgb: np.ndarray, centre: np.ndarray, radius: float) -> float:
    """Mean luminance of the pixels of ``rgb`` (H, W, 3) within ``radius`` of ``centre``."""
    x0, y0 = np.maximum(np.floor(centre - radius).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(centre + radius).astype(int) + 1, [rgb.shape[1], rgb.shape[0]])
    if x1 <= x0 or y1 <= y0:
        return np.nan
    yy, xx = np.mgrid[y0:y1, x0:x1]
    disc = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius ** 2
    return float(_luminance(rgb[y0:y1, x0:x1][disc]).mean()) if disc.any() else np.nan


def darkening(brightness: np.ndarray, rotations: np.ndarray | None = None) -> np.ndarray:
    """(P,) the 95th percentile over frames of ``max(0, 1 - b / median(b))`` per patch of
    ``brightness`` (F, P), with what is linear in the head's ``rotations`` (F, 3, 3) taken
    out first when given."""
    return np.nanpercentile(frame_darkening(brightness, rotations), 95, axis=0)


def frame_darkening(brightness: np.ndarray, rotations: np.ndarray | None = None) -> np.ndarray:
    """(F, P) each frame's ``max(0, 1 - b / median(b))`` per patch (NaN without a face): what
    :func:`darkening` takes the 95th percentile of."""
    b = np.asarray(brightness, np.float64)
    if rotations is not None:
        b = b - _lighting(b, rotations)
    return np.clip(1.0 - b / np.nanmedian(b, axis=0), 0.0, None)


def darkest_frames(per_frame: np.ndarray, n: int = DARKEST_FRAMES) -> dict[str, list[list]]:
    """Disc name -> ``[[frame, darkening], ...]``: its ``n`` darkest frames of
    :func:`frame_darkening` ``per_frame`` (F, P), darkest first; where and when a p95 comes
    from (frames without a face are never named)."""
    out = {}
    for k, name in enumerate(PATCHES):
        column = np.nan_to_num(per_frame[:, k], nan=-1.0)
        order = np.argsort(-column, kind="stable")[:n]
        out[name] = [[int(f), round(float(column[f]), 4)] for f in order if column[f] >= 0]
    return out


def _lighting(brightness: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(F, P) the part of ``brightness`` that the head rotation explains, about its median
    pose (zero there): a least-squares fit on the rotations' nine entries per patch."""
    x = np.asarray(rotations, np.float64).reshape(len(rotations), 9)
    x = x - np.median(x, axis=0)
    out = np.zeros_like(brightness)
    for k in range(brightness.shape[1]):
        ok = np.isfinite(brightness[:, k])
        if ok.sum() < 30:  # too few frames to tell the light from the face
            continue
        design = np.column_stack([x[ok], np.ones(ok.sum())])
        coef = np.linalg.lstsq(design, brightness[ok, k], rcond=None)[0]
        out[:, k] = x @ coef[:9]
    return out


def shading_of(run_dir: str | os.PathLike, progress: bool = False, skin_video: str | os.PathLike | None = None) -> dict:
    """The figures of one ``run`` folder (it needs avatar.mp4 and track.npz); the darkening
    read in ``skin_video`` (avatar.mp4's frames with a flat base colour) where given."""
    folder = Path(run_dir)
    video, source = folder / "avatar.mp4", folder / "track.npz"
    if not video.is_file() or not source.is_file():
        raise CaptureError(f"{folder}: not a run folder with avatar.mp4 and track.npz")
    with tempfile.TemporaryDirectory(prefix="capture2face-shading-") as work:
        seen = track_stage(video, RunOptions(), progress=progress, workdir=work)
    actor = Track.load(source)
    n = min(actor.n_frames, seen.n_frames)
    rotations = rotation_part(np.asarray(actor.head_pose)[:n])
    seen_frames = read_frame_darkening(video, seen, rotations)
    per_frame = seen_frames if skin_video is None else read_frame_darkening(skin_video, seen, rotations)
    seen_dark, dark = (np.nanpercentile(d, 95, axis=0) for d in (seen_frames, per_frame))
    follows = feature_follow(source_measures(actor)[:n], source_measures(seen)[:n])
    r = follows["mouth_open_r"]
    return {
        "run": folder.name,
        "frames_with_face": int(np.count_nonzero(seen.presence)),
        "darkening_p95": {name: float(d) for name, d in zip(PATCHES, dark)},
        "darkening_p95_mean": float(dark.mean()),
        "darkening_read_in": "avatar.mp4" if skin_video is None else Path(skin_video).name,
        "darkening_p95_mean_avatar": float(seen_dark.mean()),
        "darkening_frames": darkest_frames(per_frame),
        **follows,
        "met": bool(dark.mean() <= BRIGHTNESS_GOAL and r >= MOUTH_R_GOAL),
    }


def read_darkening(video: str | os.PathLike, seen: Track, rotations: np.ndarray) -> np.ndarray:
    """(P,) :func:`darkening` of each disc of ``video``, placed where ``seen`` (the tracked
    avatar.mp4) has its landmarks, over the frames of ``rotations`` (F, 3, 3)."""
    return np.nanpercentile(read_frame_darkening(video, seen, rotations), 95, axis=0)


def read_frame_darkening(video: str | os.PathLike, seen: Track, rotations: np.ndarray) -> np.ndarray:
    """(F, P) :func:`frame_darkening` of each disc of ``video`` (as :func:`read_darkening`)."""
    return frame_darkening(patch_brightness(video, seen)[:len(rotations)], rotations)


def feature_follow(actor: np.ndarray, seen: np.ndarray) -> dict[str, float]:
    """``<feature>_r`` and ``<feature>_gain`` of each of :data:`FEATURES`: how the measures
    tracked back from the video, ``seen`` (F, 6), follow the actor's, ``actor`` (F, 6)
    (frames where either has no face are left out)."""
    out = {}
    for name, cols in FEATURES.items():
        a, s = actor[:, cols].mean(1), seen[:, cols].mean(1)
        ok = np.isfinite(a) & np.isfinite(s)
        r, gain = compare(a[ok], s[ok]) if ok.sum() > 2 else (float("nan"), float("nan"))
        out[f"{name}_r"], out[f"{name}_gain"] = float(r), float(gain)
    return out


def summary_line(results: list[dict]) -> str:
    worst = max((r["darkening_p95_mean"] for r in results), default=float("nan"))
    return (f"{len(results)} runs: {sum(r['met'] for r in results)}/{len(results)} shade right and open the "
            f"mouth (cheeks and chin darken by at most {BRIGHTNESS_GOAL:.0%} at p95, worst {worst:.1%}; "
            f"mouth opening r >= {MOUTH_R_GOAL})")

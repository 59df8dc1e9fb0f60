"""Whether a cheek's darkening is the render's or the shape's: the key light's n·l over each
shading disc (``eval shading``'s cheeks and chin), at rest and over a few frames, by the
renderer's normals, by the deformed shape's smooth normals and by its facets.

    python tools/disc_light.py CLIP --character FILE --frames A:B [--cache DIR]

Each clip's track comes from tools/track_clips.py's cache, its animation from
``pipeline.retarget_stage`` as in ``capture2face run``; the frames' mean bones and weights
pose the head, which faces the light as it does at rest (the head's turn is what ``eval
shading`` takes out). A disc is the skin within 0.08 inter-ocular distances of its
landmark on the rest surface. Where the renderer's normals lose as much light as the
facets of the deformed mesh do, the render draws the shape as it is; where only the
renderer's lose it, its normals are at fault (docs/characters.md, the last of the darkening).
"""

from __future__ import annotations

import argparse

import numpy as np
from track_clips import cached_track, chosen_clips, clip_arguments


def disc_light(rig, bones: np.ndarray, weights: np.ndarray) -> dict[str, dict[str, tuple[float, float]]]:
    """{disc: {"renderer" | "smooth" | "facets": (n·l at rest, n·l posed)}} of ``rig`` posed
    by ``bones`` (B, 3) and ``weights`` (M,); "vertices": (the disc's vertex count, 0)."""
    from capture2face.eval.shading import PATCH_RADIUS_IOD, PATCHES
    from capture2face.render.renderer import DEFAULT_LIGHT_DIRECTION
    from capture2face.rig.deform import ShapeNormals, deform
    from capture2face.rig.face_rig import landmark_points

    light = np.asarray(DEFAULT_LIGHT_DIRECTION, np.float64)
    light /= np.linalg.norm(light)
    rest_p, rest_n = deform(rig, rig.bone_rest, np.zeros(rig.n_morphs, np.float32))
    pose_p, pose_n = deform(rig, bones, weights)
    shape = ShapeNormals(rig)
    smooth = shape.smooth(rest_p), shape.smooth(pose_p)
    tris = np.asarray(rig.triangles, np.int64)
    out = {}
    for name, lm in PATCHES.items():
        centre = landmark_points(rig, rest_p[None], np.array([lm]))[0, 0]
        inside = np.linalg.norm(rest_p - centre, axis=1) < PATCH_RADIUS_IOD * rig.interocular()
        faces = tris[inside[tris].any(1)]
        out[name] = {"vertices": (float(inside.sum()), 0.0),
                     "renderer": (_mean_light(rest_n[inside], light), _mean_light(pose_n[inside], light)),
                     "smooth": (_mean_light(smooth[0][inside], light), _mean_light(smooth[1][inside], light)),
                     "facets": (_facet_light(rest_p, faces, light), _facet_light(pose_p, faces, light))}
    return out


def _mean_light(normals: np.ndarray, light: np.ndarray) -> float:
    return float(np.mean(normals @ light)) if len(normals) else float("nan")


def _facet_light(positions: np.ndarray, faces: np.ndarray, light: np.ndarray) -> float:
    """Area-weighted n·l of the triangles ``faces`` (T, 3) of ``positions``."""
    p = np.asarray(positions, np.float64)
    cross = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    area = np.linalg.norm(cross, axis=1).sum()
    return float((cross @ light).sum() / area) if area > 0 else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    clip_arguments(parser)
    parser.add_argument("--character", required=True, help="a .glb / .vrm / .gltf, or 'default'")
    parser.add_argument("--frames", required=True, metavar="A:B", help="pose: the mean over frames A to B-1")
    args = parser.parse_args(argv)
    frames = slice(*(int(v) for v in args.frames.split(":")))
    clips, cache = chosen_clips(args)

    from capture2face.character.load import load_character
    from capture2face.pipeline import retarget_stage

    rig = load_character(args.character)
    for clip in clips:
        animation = retarget_stage(cached_track(clip, cache), rig)
        bones = np.asarray(animation.bone_positions)[frames].mean(0)
        weights = np.asarray(animation.blend_weights)[frames].mean(0)
        print(f"{clip.stem} frames {args.frames}: disc | vertices | n·l rest -> posed (change): renderer | "
              "smooth | facets")
        for name, row in disc_light(rig, bones, weights).items():
            cells = " | ".join(f"{a:.3f} -> {b:.3f} ({b - a:+.3f})" for k, (a, b) in row.items() if k != "vertices")
            print(f"  {name} | {row['vertices'][0]:.0f} | {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

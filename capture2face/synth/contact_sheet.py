"""The wrinkle contact sheet: neutral / stretch / compress x wrinkles off / auto / influence view.

``python -m capture2face.synth.contact_sheet [-o docs/contact_sheet.png] [--cell 256]``
renders the default avatar at each pose through the project's renderer and writes a
labelled grid (rows: poses, columns: wrinkles off, wrinkles auto, the influence heat map).
``--head`` writes the head strip instead (``docs/head.png``): the whole head from the
front, looking aside, in profile, with the mouth open, and from behind.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from capture2face.camera import framing_distance
from capture2face.io.atomic import atomic_path
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.rig.avatar import default_avatar
from capture2face.synth.trajectories import head_poses

ROWS = ("neutral", "stretch", "compress")
COLUMNS = (("wrinkles off", "off", "shaded"), ("wrinkles auto", "auto", "shaded"),
           ("influence view", "auto", "influence"))
# A three-quarter view under a raking key light from the upper side shows normal-map
# detail (wrinkles) best; the face fills most of the cell.
YAW, PITCH = 18.0, 4.0
LIGHT = (0.3, 0.9, 0.3)
FILL = 0.8
FOV_Y = 30.0


def contact_sheet(rig=None, cell: int = 256, supersample: int = 2) -> np.ndarray:
    """(3 * cell + header, 3 * cell, 3) uint8 RGB grid, labelled."""
    import cv2

    rig = rig or default_avatar()
    size = cell * supersample
    # framing_pose fills 60% of the height; come closer so the face fills FILL of it.
    closer = framing_distance(rig, FOV_Y) * (1.0 - 0.6 / FILL)
    pose = head_poses(rig, np.array([[YAW, PITCH, 0.0]]), np.array([[0.0, 0.0, closer]]), FOV_Y)[0]
    states = {
        "neutral": FrameState.at_pose(rig, pose),
        "stretch": FrameState.at_pose(rig, pose, "stretch"),
        "compress": FrameState.at_pose(rig, pose, "compress"),
    }
    cells = {}
    for label, wrinkles, view in COLUMNS:
        opts = RenderOptions(size=size, wrinkles=wrinkles, view=view, fov_y_degrees=FOV_Y)
        with Renderer.create_from_options(rig, opts) as renderer:
            for row in ROWS:
                state = states[row]
                state.light_direction = np.asarray(LIGHT, np.float32) / np.linalg.norm(LIGHT)
                image = renderer.render(state)
                cells[row, label] = cv2.resize(image, (cell, cell), interpolation=cv2.INTER_AREA)
    header, gutter = 28, 84
    sheet = np.full((header + 3 * cell, gutter + 3 * cell, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for c, (label, _, _) in enumerate(COLUMNS):
        x = gutter + c * cell
        (w, _), _ = cv2.getTextSize(label, font, 0.55, 1)
        cv2.putText(sheet, label, (x + (cell - w) // 2, 20), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
        for r, row in enumerate(ROWS):
            sheet[header + r * cell:header + (r + 1) * cell, x:x + cell] = cells[row, label]
    for r, row in enumerate(ROWS):
        cv2.putText(sheet, row, (6, header + r * cell + cell // 2), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return sheet


# The head strip: (label, head yaw, pitch, eye yaw, eye pitch, pose).
HEAD_VIEWS = (("front", 0.0, 0.0, 0.0, 0.0, None), ("looking aside", 20.0, 0.0, -28.0, 6.0, None),
              ("profile", 75.0, 0.0, 0.0, 0.0, None), ("mouth open", -25.0, -8.0, 0.0, -10.0, "stretch"),
              ("back", 150.0, 8.0, 0.0, 0.0, None))


def head_sheet(rig=None, cell: int = 256, supersample: int = 2) -> np.ndarray:
    """(cell + header, 5 * cell, 3) uint8 RGB strip of the whole head, labelled."""
    import cv2

    rig = rig or default_avatar()
    size = cell * supersample
    back = 0.05 * framing_distance(rig, FOV_Y)  # about the framing distance: the whole head, not just the face
    header = 28
    sheet = np.full((header + cell, len(HEAD_VIEWS) * cell, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    with Renderer.create_from_options(rig, RenderOptions(size=size, wrinkles="auto", fov_y_degrees=FOV_Y)) as renderer:
        for c, (label, yaw, pitch, eye_yaw, eye_pitch, pose_name) in enumerate(HEAD_VIEWS):
            pose = head_poses(rig, np.array([[yaw, pitch, 0.0]]), np.array([[0.0, -2.0, back]]), FOV_Y)[0]
            state = FrameState.at_pose(rig, pose, pose_name)
            state.eye_rotation = np.array([[eye_yaw, eye_pitch]] * 2, np.float32)
            state.light_direction = np.asarray(LIGHT, np.float32) / np.linalg.norm(LIGHT)
            image = cv2.resize(renderer.render(state), (cell, cell), interpolation=cv2.INTER_AREA)
            sheet[header:, c * cell:(c + 1) * cell] = image
            (w, _), _ = cv2.getTextSize(label, font, 0.55, 1)
            cv2.putText(sheet, label, (c * cell + (cell - w) // 2, 20), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return sheet


def write_contact_sheet(path: str | os.PathLike, cell: int = 256, head: bool = False) -> None:
    import cv2

    sheet = head_sheet(cell=cell) if head else contact_sheet(cell=cell)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {path}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="docs/contact_sheet.png")
    parser.add_argument("--cell", type=int, default=256, help="pixels per cell")
    parser.add_argument("--head", action="store_true", help="the whole-head strip instead of the wrinkle grid")
    args = parser.parse_args(argv)
    write_contact_sheet(args.output, args.cell, head=args.head)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The range-of-motion protocol as an illustrated sheet: the neutral, then each step.

    python tools/protocol_sheet.py docs/calibration_protocol.jpg [--character C.glb] [--cell 256]

Each cell is an ARKit character, frontal, at the step's target weights (the frame of the
step's hold in ``capture2face synth --rom``'s take, so the eyes turn in the look steps),
with the step's number, name and instruction under it, 7 cells a row. docs/calibration.md
shows it.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import cv2
import numpy as np

from capture2face.calibration.protocol import EASE, GAP, HOLD, LEAD_NEUTRAL, PROTOCOL
from capture2face.camera import framing_distance
from capture2face.character.load import load_character
from capture2face.io.atomic import atomic_path
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.synth import actor_rig
from capture2face.synth.actor import rom_performance
from capture2face.synth.trajectories import head_poses

DEFAULT_CHARACTER = Path(__file__).resolve().parents[2] / "shared" / "characters" / "ict-a.glb"
COLUMNS, FOV_Y, FILL, RAISE, SUPERSAMPLE, FPS = 7, 30.0, 0.95, 0.04, 2, 30.0
LIGHT = np.array([0.2, 0.5, 1.0], np.float32)  # frontal, a little from above: even light, as asked of the actor
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _wrap(text: str, width: int, scale: float) -> list[str]:
    """``text`` in lines no wider than ``width`` pixels."""
    lines: list[str] = []
    for word in text.split():
        wider = f"{lines[-1]} {word}" if lines else word
        if lines and cv2.getTextSize(wider, FONT, scale, 1)[0][0] <= width:
            lines[-1] = wider
        else:
            lines.append(word)
    return lines


def _cell(image: np.ndarray, title: str, text: str, cell: int) -> np.ndarray:
    """(cell + band, cell, 3) the picture with ``title`` and ``text`` under it."""
    scale = 0.45 * cell / 256
    line = max(8, int(20 * cell / 256))
    lines = _wrap(text, cell - 8, scale)
    out = np.full((cell + line * (len(lines) + 1) + line // 2, cell, 3), 255, np.uint8)
    out[:cell] = cv2.resize(image, (cell, cell), interpolation=cv2.INTER_AREA)
    for k, words in enumerate([title, *lines]):
        cv2.putText(out, words, (4, cell + line * (k + 1)), FONT, scale, (0, 0, 0), 2 if k == 0 else 1, cv2.LINE_AA)
    return out


def protocol_sheet(character=DEFAULT_CHARACTER, cell: int = 256) -> np.ndarray:
    """(H, COLUMNS * cell, 3) uint8 RGB: the neutral and the protocol's steps, labelled."""
    rig = actor_rig(load_character(os.fspath(character)))
    take = rom_performance(rig, fps=FPS, head_motion=False)
    per_step = 2 * EASE + HOLD + GAP
    holds = [0] + [round((LEAD_NEUTRAL + k * per_step + EASE + HOLD / 2) * FPS) for k in range(len(PROTOCOL))]
    labels = [("0  neutral", "Relaxed face, eyes ahead (start and between steps)")]
    labels += [(f"{k}  {s.name}", s.instruction) for k, s in enumerate(PROTOCOL, 1)]
    # framing_pose fills 60% of the height; come closer so the face fills FILL of it, and
    # raise it by RAISE of the frame so an open jaw's chin stays in (the crown may go).
    far = framing_distance(rig, FOV_Y)
    near = far * 0.6 / FILL
    lift = RAISE * 2.0 * near * np.tan(np.radians(FOV_Y) / 2.0)
    pose = head_poses(rig, np.zeros((1, 3)), np.array([[0.0, lift, far - near]]), FOV_Y)[0]
    cells = []
    opts = RenderOptions(size=cell * SUPERSAMPLE, fov_y_degrees=FOV_Y)
    with Renderer.create_from_options(rig, opts) as renderer:
        for frame, (title, text) in zip(holds, labels):
            state = FrameState.at_pose(rig, pose)
            state.blend_weights = take.blend_weights[frame]
            if take.eye_rotation is not None:
                state.eye_rotation = take.eye_rotation[frame]
            state.light_direction = LIGHT / np.linalg.norm(LIGHT)
            cells.append(_cell(renderer.render(state), title, text, cell))
    band = max(c.shape[0] for c in cells)
    cells += [np.full_like(cells[0], 255)] * (-len(cells) % COLUMNS)
    rows = [np.concatenate([np.pad(c, ((0, band - c.shape[0]), (0, 0), (0, 0)), constant_values=255)
                            for c in cells[r:r + COLUMNS]], 1) for r in range(0, len(cells), COLUMNS)]
    return np.concatenate(rows, 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="the sheet (.jpg or .png)")
    parser.add_argument("--character", default=os.fspath(DEFAULT_CHARACTER), help="an ARKit character (.glb)")
    parser.add_argument("--cell", type=int, default=256, help="pixels per cell")
    args = parser.parse_args(argv)
    sheet = protocol_sheet(args.character, args.cell)
    params = [cv2.IMWRITE_JPEG_QUALITY, 85] if Path(args.output).suffix.lower() in (".jpg", ".jpeg") else []
    with atomic_path(args.output) as tmp:  # keeps the suffix OpenCV picks the format from
        if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), params):
            raise SystemExit(f"could not write {args.output}")
    print(f"wrote {args.output} ({sheet.shape[1]} x {sheet.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

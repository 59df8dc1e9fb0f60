"""Contact sheets: square cells of images in rows, each cell labelled, under a title.

Plain OpenCV drawing on (H, W, 3) uint8 RGB arrays; what goes in the cells is the
caller's (:mod:`capture2face.eval.characters`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path

BACKGROUND = (24, 24, 24)
TEXT = (235, 235, 235)
LABEL_BAND = 0.11  # label band height, a fraction of the cell
GAP = 4  # pixels between cells


@dataclass
class Cell:
    """One cell: an image (any size; fitted into the square cell) and its label (None:
    an empty cell with ``label`` written in it)."""

    image: np.ndarray | None
    label: str = ""


def square_crop(rgb: np.ndarray, centre, half: float) -> np.ndarray:
    """The square of ``rgb`` (H, W, 3) centred on ``centre`` (x, y) pixels, ``half`` pixels
    to each side; what lies outside the image is black."""
    half = max(1, int(round(half)))
    cx, cy = (int(round(c)) for c in centre)
    out = np.zeros((2 * half, 2 * half, 3), np.uint8)
    x0, y0 = cx - half, cy - half
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + 2 * half, rgb.shape[1]), min(y0 + 2 * half, rgb.shape[0])
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = rgb[sy0:sy1, sx0:sx1]
    return out


def _fit(image: np.ndarray, cell: int) -> np.ndarray:
    """``image`` scaled to fit a ``cell`` square, centred on the background."""
    import cv2

    h, w = image.shape[:2]
    scale = cell / max(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = cv2.resize(image, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)
    out = np.full((cell, cell, 3), BACKGROUND, np.uint8)
    y, x = (cell - size[1]) // 2, (cell - size[0]) // 2
    out[y:y + size[1], x:x + size[0]] = small
    return out


def _text(img: np.ndarray, text: str, x: int, y: int, scale: float) -> None:
    import cv2

    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, TEXT, 1, cv2.LINE_AA)


def _cell_image(cell: Cell, size: int) -> np.ndarray:
    band = max(12, int(size * LABEL_BAND))
    out = np.full((size + band, size, 3), BACKGROUND, np.uint8)
    if cell.image is not None:
        out[band:] = _fit(np.asarray(cell.image, np.uint8), size)
    _text(out, cell.label, 3, band - 4, _font_scale(cell.label, size, band))
    return out


def _font_scale(text: str, width: int, band: int) -> float:
    """The largest scale (up to the band's height) at which ``text`` fits ``width``."""
    import cv2

    scale = band / 30.0
    w = cv2.getTextSize(text or " ", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
    return scale * min(1.0, (width - 6) / max(w, 1))


def draw_sheet(rows: list[list[Cell]], cell: int, title: list[str]) -> np.ndarray:
    """(H, W, 3) uint8 RGB: ``title`` lines, then ``rows`` of ``cell``-px cells (a label
    band above each)."""
    columns = max(len(r) for r in rows)
    width = columns * cell + (columns + 1) * GAP
    line = max(14, int(cell * 0.1))
    head = np.full((GAP + line * len(title), width, 3), BACKGROUND, np.uint8)
    for k, text in enumerate(title):
        _text(head, text, GAP, GAP + line * (k + 1) - 4, _font_scale(text, width - 2 * GAP, line))
    parts = [head]
    for row in rows:
        images = [_cell_image(c, cell) for c in row]
        band = np.full((images[0].shape[0] + GAP, width, 3), BACKGROUND, np.uint8)
        for i, img in enumerate(images):
            x = GAP + i * (cell + GAP)
            band[GAP:, x:x + cell] = img
        parts.append(band)
    parts.append(np.full((GAP, width, 3), BACKGROUND, np.uint8))
    return np.concatenate(parts)


def write_image(rgb: np.ndarray, path: str | os.PathLike) -> None:
    """Write ``rgb`` as PNG or JPEG (the suffix says), atomically."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:  # keeps the suffix OpenCV picks the format from
        if not cv2.imwrite(str(tmp), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise CaptureError(f"{path}: cannot write the picture")

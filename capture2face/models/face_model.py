"""Where the MediaPipe Face Landmarker model (``face_landmarker.task``) comes from."""

from __future__ import annotations

import os
from pathlib import Path

from capture2face.errors import CaptureError

ENV_VAR = "CAPTURE2FACE_FACE_MODEL"


def find_face_model(path: str | os.PathLike | None = None) -> Path:
    """Resolve the model file: ``path`` (``--face-model``), else ``$CAPTURE2FACE_FACE_MODEL``,
    else the copy bundled with this package (``capture2face/models/face_landmarker.task``,
    MediaPipe's model, Apache-2.0: see the NOTICE beside it).

    Raises:
        CaptureError: naming the three ways to provide one when none is found.
    """
    for given, source in ((path, "--face-model"), (os.environ.get(ENV_VAR), f"${ENV_VAR}")):
        if given:
            return _model_file(Path(given), source)
    bundled = bundled_face_model()
    if bundled.is_file():
        return bundled
    raise CaptureError(
        f"no MediaPipe face model found: the bundled {bundled} is missing (a broken "
        f"install: reinstall capture2face), or pass --face-model PATH or set ${ENV_VAR}"
    )


def _model_file(path: Path, source: str) -> Path:
    if path.is_dir():
        raise CaptureError(f"face model {path} (from {source}) is a folder; give the model file itself "
                           "(face_landmarker.task)")
    if not path.is_file():
        raise CaptureError(f"face model {path} (from {source}) does not exist")
    return path


def bundled_face_model() -> Path:
    """The ``face_landmarker.task`` shipped inside the package (package data)."""
    return Path(__file__).resolve().parent.parent / "models" / "face_landmarker.task"

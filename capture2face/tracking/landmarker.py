"""MediaPipe Face Landmarker (Tasks API, VIDEO mode) behind a small wrapper.

One call per frame gives the face that continues the track: 478 landmarks (normalized and
in pixels), MediaPipe's relative depth, the 52 blendshape scores and the facial
transformation matrix. With several faces in view, the face closest to the previous one
(centre distance and size change, relative to the previous face size) is kept; the first
face taken is the largest one.
"""

from __future__ import annotations

import os

# MediaPipe / TFLite / absl log to stderr from C++; quiet them before the first import.
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import contextlib  # noqa: E402
import sys  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402

from capture2face.errors import CaptureError  # noqa: E402
from capture2face.tracking.model import find_face_model  # noqa: E402

N_LANDMARKS = 478

#: MediaPipe's blendshape categories in output order (index 0 "_neutral" is a bias term).
BLENDSHAPE_NAMES = [
    "_neutral", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft",
    "browOuterUpRight", "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft",
    "eyeBlinkRight", "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight",
    "eyeLookOutLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft",
    "eyeSquintRight", "eyeWideLeft", "eyeWideRight", "jawForward", "jawLeft", "jawOpen",
    "jawRight", "mouthClose", "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft",
    "mouthFrownRight", "mouthFunnel", "mouthLeft", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthPressLeft", "mouthPressRight", "mouthPucker", "mouthRight", "mouthRollLower",
    "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthSmileLeft", "mouthSmileRight",
    "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "noseSneerLeft", "noseSneerRight",
]


@dataclass
class LandmarkerOptions:
    """Face Landmarker settings.

    Attributes:
        face_model: path of ``face_landmarker.task`` (None: ``find_face_model`` decides).
        num_faces: faces MediaPipe looks for; >1 lets the tracker pick the one that
            continues the track when several people are in view.
        min_detection_confidence, min_presence_confidence, min_tracking_confidence:
            MediaPipe's thresholds.
    """

    face_model: str | os.PathLike | None = None
    num_faces: int = 1
    min_detection_confidence: float = 0.5
    min_presence_confidence: float = 0.5
    min_tracking_confidence: float = 0.5


@dataclass
class FaceObservation:
    """One frame's face.

    Attributes:
        landmarks_norm: (478, 3) float32 MediaPipe's normalized landmarks: x, y in [0, 1] of
            the image width/height (origin top-left), z relative depth on the scale of x.
        landmarks_px: (478, 2) float32 pixels (x right, y down).
        depth: (478,) float32 relative depth in pixels (z * width), smaller = nearer.
        blendshapes: (52,) float32 scores, order :data:`BLENDSHAPE_NAMES`.
        matrix: (4, 4) float32 MediaPipe's facial transformation matrix (head -> camera, cm).
        n_faces: faces MediaPipe saw in this frame.
    """

    landmarks_norm: np.ndarray
    landmarks_px: np.ndarray
    depth: np.ndarray
    blendshapes: np.ndarray
    matrix: np.ndarray
    n_faces: int


@contextlib.contextmanager
def _quiet_stderr():
    """Send file descriptor 2 to /dev/null: MediaPipe's C++ start-up chatter ignores
    GLOG_minloglevel (absl, TFLite and XNNPACK each log on their own). Set
    CAPTURE2FACE_MEDIAPIPE_LOGS=1 to see it."""
    if os.environ.get("CAPTURE2FACE_MEDIAPIPE_LOGS"):
        yield
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


class FaceLandmarker:
    """A MediaPipe Face Landmarker in VIDEO mode; use as a context manager.

    >>> with FaceLandmarker.create_from_options(LandmarkerOptions()) as lm:
    ...     obs = lm.detect(rgb, t_seconds)   # FaceObservation or None
    """

    def __init__(self, landmarker, options: LandmarkerOptions):
        self._lm = landmarker
        self.options = options
        self._last_ms = -1
        self._prev_centre: np.ndarray | None = None
        self._prev_size = 0.0

    @classmethod
    def create_from_options(cls, options: LandmarkerOptions | None = None) -> "FaceLandmarker":
        options = options or LandmarkerOptions()
        model = find_face_model(options.face_model)
        from mediapipe.tasks.python import BaseOptions, vision

        mp_options = vision.FaceLandmarkerOptions(
            base_options=BaseOptions(model_asset_path=str(model)),
            running_mode=vision.RunningMode.VIDEO,
            num_faces=max(1, int(options.num_faces)),
            min_face_detection_confidence=options.min_detection_confidence,
            min_face_presence_confidence=options.min_presence_confidence,
            min_tracking_confidence=options.min_tracking_confidence,
            output_face_blendshapes=True,
            output_facial_transformation_matrixes=True,
        )
        try:
            with _quiet_stderr():
                landmarker = vision.FaceLandmarker.create_from_options(mp_options)
        except (RuntimeError, ValueError) as exc:
            raise CaptureError(f"{model}: not a usable MediaPipe face model ({exc})") from None
        return cls(landmarker, options)

    def close(self) -> None:
        if self._lm is not None:
            self._lm.close()
            self._lm = None

    def __enter__(self) -> "FaceLandmarker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def detect(self, rgb: np.ndarray, t_seconds: float) -> FaceObservation | None:
        """Landmarks of the face that continues the track in ``rgb`` (H, W, 3) uint8."""
        import mediapipe as mp

        if self._lm is None:
            raise RuntimeError("FaceLandmarker is closed")
        # VIDEO mode needs strictly increasing integer milliseconds.
        ms = max(int(round(t_seconds * 1000.0)), self._last_ms + 1)
        self._last_ms = ms
        image = mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        result = self._lm.detect_for_video(image, ms)
        faces = result.face_landmarks
        if not faces:
            return None
        h, w = rgb.shape[:2]
        norms = [np.array([(p.x, p.y, p.z) for p in face], np.float32) for face in faces]
        k = self._choose(norms, w, h)
        norm = norms[k]
        if result.face_blendshapes and len(result.face_blendshapes) > k:
            scores = np.array([c.score for c in result.face_blendshapes[k]], np.float32)
        else:
            scores = np.zeros(len(BLENDSHAPE_NAMES), np.float32)
        if result.facial_transformation_matrixes and len(result.facial_transformation_matrixes) > k:
            matrix = np.asarray(result.facial_transformation_matrixes[k], np.float32).reshape(4, 4)
        else:
            matrix = np.eye(4, dtype=np.float32)
        px = norm[:, :2] * np.array([w, h], np.float32)
        return FaceObservation(
            landmarks_norm=norm, landmarks_px=px, depth=norm[:, 2] * w,
            blendshapes=scores, matrix=matrix, n_faces=len(faces),
        )

    def _choose(self, norms: list[np.ndarray], w: int, h: int) -> int:
        """Index of the face continuing the track (largest face when there is no track)."""
        scale = np.array([w, h], np.float32)
        centres = np.array([n[:, :2].mean(0) * scale for n in norms])
        sizes = np.array([np.ptp(n[:, :2] * scale, axis=0).max() for n in norms])
        if self._prev_centre is None or len(norms) == 1:
            k = int(np.argmax(sizes)) if self._prev_centre is None else 0
        else:
            ref = max(self._prev_size, 1.0)
            cost = (np.linalg.norm(centres - self._prev_centre, axis=1) / ref
                    + np.abs(np.log(sizes / ref)))
            k = int(np.argmin(cost))
        self._prev_centre, self._prev_size = centres[k], float(sizes[k])
        return k

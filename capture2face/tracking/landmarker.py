"""MediaPipe Face Landmarker (Tasks API, VIDEO mode) behind a small wrapper.

One call per frame gives the face that continues the track: 478 landmarks (normalized and
in pixels), MediaPipe's relative depth, the 52 blendshape scores and the facial
transformation matrix.

Several faces: MediaPipe is asked for up to ``num_faces`` faces until the face to track is
chosen (:attr:`LandmarkerOptions.faces`/:attr:`LandmarkerOptions.face`); from then on the
face closest to the previous one (centre distance and size change, relative to the
previous face size) is kept. Looking for several faces costs ~25-40% of the tracking speed
(the face detector then runs on every frame where fewer are tracked), so once only one face
has been seen for ``settle_frames`` frames a single-face landmarker tracks it and the
several-face one looks again every ``probe_every`` frames (and whenever the face is lost
or jumps); a second face seen there brings the several-face tracking back.
"""

from __future__ import annotations

import os

# MediaPipe / TFLite / absl log to stderr from C++; quiet them before the first import.
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import contextlib
import importlib
import sys
import types
from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.models.face_model import find_face_model
from capture2face.topology import BLENDSHAPE_NAMES, N_LANDMARKS


@dataclass
class LandmarkerOptions:
    """Face Landmarker settings.

    Attributes:
        face_model: path of ``face_landmarker.task`` (None: ``find_face_model`` decides).
        num_faces: the most faces MediaPipe looks for (and counts) at once; 1: a single
            face, no choice, no count.
        faces: which face starts the track: "largest" or "center" (nearest the image
            centre); then the one continuing it is followed.
        face: instead, the face with this index (0-based, left to right by face centre)
            in the first frame with more than ``face`` faces; frames before it have none.
        probe_every, settle_frames: see the module docstring.
        min_detection_confidence, min_presence_confidence, min_tracking_confidence:
            MediaPipe's thresholds.
        still_images: each image on its own (MediaPipe's IMAGE mode): no tracking from
            the image before, none of VIDEO mode's smoothing, which pulls an image's
            landmarks towards the previous image's (renders of a character, not a clip).
    """

    face_model: str | os.PathLike | None = None
    num_faces: int = 4
    faces: str = "largest"
    face: int | None = None
    probe_every: int = 30
    settle_frames: int = 15
    min_detection_confidence: float = 0.5
    min_presence_confidence: float = 0.5
    min_tracking_confidence: float = 0.5
    still_images: bool = False

    def validate(self) -> None:
        """The face choice: one line ``CaptureError`` each, named after the command line's
        flags (:meth:`capture2face.tracking.TrackOptions.validate` asks it too)."""
        if self.faces not in FACE_CHOICES:
            raise CaptureError(f"--faces must be one of {', '.join(FACE_CHOICES)} (got {self.faces!r})")
        if self.face is not None and not 0 <= int(self.face) <= MAX_FACE:
            raise CaptureError(f"--face must be 0..{MAX_FACE} (got {self.face})")


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
        n_faces: faces MediaPipe saw in this frame (1 in the frames tracked by the
            single-face landmarker).
    """

    landmarks_norm: np.ndarray
    landmarks_px: np.ndarray
    depth: np.ndarray
    blendshapes: np.ndarray
    matrix: np.ndarray
    n_faces: int


def face_boxes(points_px: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Centres (K, 2) and sizes (K,) in pixels of K faces' (478, 2) pixel landmarks (the
    size: the larger side of their bounding box): what tracking compares to follow one
    face from frame to frame and across segments."""
    centres = np.array([p.mean(0) for p in points_px])
    sizes = np.array([np.ptp(p, axis=0).max() for p in points_px])
    return centres, sizes


def stack_observations(obs: list[FaceObservation | None]) -> dict:
    """Per-frame faces (None: no face) as arrays: ``norm`` (k, 478, 3) float32,
    ``scores`` (k, 52) float64, ``presence`` (k,) bool (rows without a face are zeros),
    ``n_faces_max`` (the most faces seen at once)."""
    presence = np.array([o is not None for o in obs], bool)
    idx = np.flatnonzero(presence)
    norm = np.zeros((len(obs), N_LANDMARKS, 3), np.float32)
    scores = np.zeros((len(obs), len(BLENDSHAPE_NAMES)), np.float64)
    if idx.size:
        norm[idx] = np.stack([obs[i].landmarks_norm for i in idx])
        scores[idx] = np.stack([obs[i].blendshapes for i in idx])
    return {"norm": norm, "scores": scores, "presence": presence,
            "n_faces_max": max((obs[i].n_faces for i in idx), default=0)}


class _Deferred(types.ModuleType):
    """A module imported on its first attribute access (:func:`defer_pyplot`)."""

    def __getattr__(self, attr: str):
        for name in [n for n, m in sys.modules.items() if isinstance(m, _Deferred)]:
            del sys.modules[name]
        return getattr(importlib.import_module(self.__name__), attr)


def defer_pyplot() -> None:
    """Defer matplotlib until something uses it. MediaPipe's ``vision`` package imports
    matplotlib.pyplot for drawing helpers this project never calls: ~0.5 s of every
    process's start-up (1-2 s on a loaded 2-core machine). For processes this project
    owns (the CLI, tracking workers); any later use of matplotlib imports it as usual."""
    if "matplotlib" not in sys.modules:
        top, pyplot = _Deferred("matplotlib"), _Deferred("matplotlib.pyplot")
        top.pyplot = pyplot
        sys.modules["matplotlib"], sys.modules["matplotlib.pyplot"] = top, pyplot


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


FACE_CHOICES = ("largest", "center")
MAX_FACE = 15  # the highest --face: MediaPipe then looks for MAX_FACE + 1 faces in every frame
_JUMP = 1.0  # a single-face result moving more than ~one face size in a frame is re-checked


def _mediapipe_landmarker(model, options: LandmarkerOptions, num_faces: int):
    from mediapipe.tasks.python import BaseOptions, vision

    mp_options = vision.FaceLandmarkerOptions(
        base_options=BaseOptions(model_asset_path=str(model)),
        running_mode=vision.RunningMode.IMAGE if options.still_images else vision.RunningMode.VIDEO,
        num_faces=num_faces,
        min_face_detection_confidence=options.min_detection_confidence,
        min_face_presence_confidence=options.min_presence_confidence,
        min_tracking_confidence=options.min_tracking_confidence,
        output_face_blendshapes=True,
        output_facial_transformation_matrixes=True,
    )
    try:
        with _quiet_stderr():
            return vision.FaceLandmarker.create_from_options(mp_options)
    except (RuntimeError, ValueError) as exc:
        raise CaptureError(f"{model}: not a usable MediaPipe face model ({exc})") from None


class FaceLandmarker:
    """A MediaPipe Face Landmarker in VIDEO mode; use as a context manager.

    >>> with FaceLandmarker.create_from_options(LandmarkerOptions()) as lm:
    ...     obs = lm.detect(rgb, t_seconds)   # FaceObservation or None

    After the frames: ``n_faces_max`` (most faces seen at once) and ``chosen`` (whether
    the face to track was found).
    """

    def __init__(self, landmarker, options: LandmarkerOptions, model=None):
        self._lm = landmarker  # looks for self.max_faces faces
        self._single = None  # the single-face landmarker, made on first use
        self._model = model
        self.options = options
        self.max_faces = self.faces_wanted(options)
        self._last_ms = -1
        self._prev_centre: np.ndarray | None = None
        self._prev_size = 0.0
        self.chosen = False
        self.n_faces_max = 0
        self._one_face_run = 0  # consecutive several-face looks that saw one face
        self._since_probe = 0
        self._use_single = self.max_faces == 1

    @staticmethod
    def faces_wanted(options: LandmarkerOptions) -> int:
        n = max(1, int(options.num_faces))
        return max(n, int(options.face) + 1) if options.face is not None else n

    @classmethod
    def create_from_options(cls, options: LandmarkerOptions | None = None) -> FaceLandmarker:
        options = options or LandmarkerOptions()
        options.validate()
        model = find_face_model(options.face_model)
        return cls(_mediapipe_landmarker(model, options, cls.faces_wanted(options)), options, model)

    def prepare(self) -> None:
        """Load the single-face landmarker now rather than at its first use mid-clip
        (a process that waits for work does it while it waits)."""
        if self._single is None and self._lm is not None:
            self._single = (self._lm if self.max_faces == 1
                            else _mediapipe_landmarker(self._model, self.options, 1))

    def close(self) -> None:
        for lm in {id(x): x for x in (self._lm, self._single) if x is not None}.values():
            lm.close()  # once each (the single-face one is the main one when max_faces == 1)
        self._lm = self._single = None

    def __enter__(self) -> FaceLandmarker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def detect(self, rgb: np.ndarray, t_seconds: float) -> FaceObservation | None:
        """Landmarks of the tracked face in ``rgb`` (H, W, 3) uint8 (None: no face, or the
        face asked for by index not chosen yet)."""
        import mediapipe as mp

        if self._lm is None:
            raise RuntimeError("FaceLandmarker is closed")
        # VIDEO mode needs strictly increasing integer milliseconds.
        ms = max(int(round(t_seconds * 1000.0)), self._last_ms + 1)
        self._last_ms = ms
        image = mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        h, w = rgb.shape[:2]
        if self.options.still_images:
            result = self._lm.detect(image)
            norms = self._norms(result)
            self.n_faces_max = max(self.n_faces_max, len(norms))
            k = self._choose(norms, w, h) if norms else None
            return None if k is None else self._observation(result, norms, w, h, k)
        if self._use_single:
            self.prepare()
            result = self._single.detect_for_video(image, ms)
            self._since_probe += 1
            norms = self._norms(result)
            boxes = self._boxes(norms, w, h)  # for _continues and _choose alike
            if self.max_faces == 1:
                self.n_faces_max = max(self.n_faces_max, len(norms))
                return self._observation(result, norms, w, h, self._choose(norms, w, h, boxes)) if norms else None
            probe = self._since_probe >= max(1, int(self.options.probe_every))
            if norms and not probe and self._continues(boxes):
                return self._observation(result, norms, w, h, self._choose(norms, w, h, boxes))
            # Lost, jumped or time to look again: the several-face landmarker decides.
            self._since_probe = 0
            self._one_face_run = 0
            self._use_single = False
            several = self._lm.detect_for_video(image, ms)
            n = len(several.face_landmarks)
            self.n_faces_max = max(self.n_faces_max, n)
            if norms and n <= 1 and self._continues(boxes):
                self._use_single = True  # still alone: stay on the single-face landmarker
                return self._observation(result, norms, w, h, self._choose(norms, w, h, boxes))
            result = several
        else:
            result = self._lm.detect_for_video(image, ms)
        norms = self._norms(result)
        n = len(norms)
        self.n_faces_max = max(self.n_faces_max, n)
        self._one_face_run = self._one_face_run + 1 if n == 1 and self.chosen else 0
        if self._one_face_run >= max(1, int(self.options.settle_frames)):
            self._use_single, self._since_probe = True, 0
        if not norms:
            return None
        k = self._choose(norms, w, h)
        return None if k is None else self._observation(result, norms, w, h, k)

    @staticmethod
    def _norms(result) -> list[np.ndarray]:
        return [np.array([(p.x, p.y, p.z) for p in face], np.float32) for face in result.face_landmarks or []]

    @staticmethod
    def _observation(result, norms: list[np.ndarray], w: int, h: int, k: int) -> FaceObservation:
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
            blendshapes=scores, matrix=matrix, n_faces=len(norms),
        )

    @staticmethod
    def _boxes(norms: list[np.ndarray], w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
        scale = np.array([w, h], np.float32)
        return face_boxes([n[:, :2] * scale for n in norms])

    def _continues(self, boxes: tuple[np.ndarray, np.ndarray]) -> bool:
        """Whether a single-face result (its :meth:`_boxes`) is plausibly the face tracked
        in the frame before."""
        if self._prev_centre is None:
            return False
        centres, sizes = boxes
        ref = max(self._prev_size, 1.0)
        return float(np.linalg.norm(centres[0] - self._prev_centre) / ref
                     + abs(np.log(max(sizes[0], 1e-3) / ref))) < _JUMP

    def _choose(self, norms: list[np.ndarray], w: int, h: int, boxes=None) -> int | None:
        """Index of the tracked face among ``norms`` (``boxes``: their :meth:`_boxes`, if
        already measured): before the choice, the one the options ask for (None while the
        face asked for by index is not in view); after, the one continuing the track."""
        centres, sizes = self._boxes(norms, w, h) if boxes is None else boxes
        if not self.chosen:
            face = self.options.face
            if face is not None:
                if len(norms) <= int(face):
                    return None
                k = int(np.argsort(centres[:, 0], kind="stable")[int(face)])
            elif self.options.faces == "center":
                k = int(np.argmin(np.linalg.norm(centres - np.array([w / 2, h / 2]), axis=1)))
            else:
                k = int(np.argmax(sizes))
            self.chosen = True
        elif len(norms) == 1:
            k = 0
        else:
            ref = max(self._prev_size, 1.0)
            cost = (np.linalg.norm(centres - self._prev_centre, axis=1) / ref
                    + np.abs(np.log(sizes / ref)))
            k = int(np.argmin(cost))
        self._prev_centre, self._prev_size = centres[k], float(sizes[k])
        return k

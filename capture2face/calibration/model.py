"""``ActorCalibration``: what a range-of-motion take taught about one actor, and its JSON
(``actor.json``: readable and editable; the per-curve ``gain`` and ``offset`` are what a
user tunes). Several takes of the actor calibrate together: each is learned on its own and
the clip's curves are the mean of each take's (:attr:`ActorCalibration.more_takes`)."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field

import numpy as np

from capture2face.errors import CaptureError
from capture2face.io.atomic import write_text_atomic

FORMAT = "capture2face.ActorCalibration/1"
LEARNED = ("rest", "pose_model", "basis", "noise")  # actor.json's arrays, after what a user edits
SOURCES = ("tracker", "expressions", "geometry")  # where a calibrated curve comes from


@dataclass
class StepFit:
    """One protocol step as found in the take.

    Attributes:
        name: the step (:data:`~capture2face.calibration.protocol.PROTOCOL`).
        found: whether the take shows it (False: missing, named in a warning).
        frames: (first, last) frame of its motion in the take, or None.
        hold: (first, last) frame of the hold it was learned from, or None.
        match: how like the step the tracker's own reading of the hold is (cosine of its
            scores' change against the step's ARKit weights, -1..1), or None.
        before: ARKit name -> the uncalibrated curve at the hold (its mean), for the report.
        after: the same, calibrated.
    """

    name: str
    found: bool
    frames: tuple[int, int] | None = None
    hold: tuple[int, int] | None = None
    match: float | None = None
    before: dict[str, float] = field(default_factory=dict)
    after: dict[str, float] = field(default_factory=dict)


@dataclass
class ActorCalibration:
    """One actor's calibration. K = steps found, D = features per frame
    (:func:`~capture2face.calibration.features.frame_features`), S = scores.

    Attributes:
        source: the ROM take it was learned from.
        fps: the take's frame rate.
        steps: every protocol step, found or not.
        rest_face, rest_landmarks: (478, 3) float32 the actor's rest in the take's head
            coordinates (:class:`~capture2face.tracking.rest.ActorRest`'s face and landmarks).
        rest_scores: (S,) float32 the scores at rest.
        score_names: S names of the tracker's scores.
        pose_model: (P, D) float32 how this actor's features shift with the head's pose
            (:func:`~capture2face.calibration.features.pose_terms`), taken off every frame.
        basis: (K, D) float32 each found step's feature change at its hold.
        basis_steps: K names of the steps the basis rows belong to.
        noise: (K,) float32 each step's weight that the take's idle frames reach (its 90th
            percentile there): weights below it are the tracker's noise.
        curves: ARKit name -> {"source", "gain", "offset", "steps", "explained_by"}: the
            calibrated curve is ``clip(gain * x + offset, 0, 1)``, ``x`` the tracker's own
            curve (source "tracker"), the face's geometry read against this take's rest
            laid onto the clip ("geometry", ``retarget.arkit.GEOMETRIC``), or the mix
            ``sum_k w_k target_k`` of the actor's expressions that show it ("expressions"),
            less ``sum_j b_j w_j`` over ``explained_by`` (step -> b: what other regions'
            steps raise of it). A tracker's
            curve with a ``score`` ({"share", "gain", "offset"}, jawOpen) is first averaged
            at that share with ``clip(gain * s + offset, 0, 1)``, ``s`` the tracker's own
            score calibrated to rest (the curve itself is the face's geometry).
        warnings: what the take lacked or showed badly.
        more_takes: the calibrations of the actor's other takes, each learned on its own
            (``calibrate`` given several takes); the clip's curves are the mean of each
            take's reading (:attr:`takes`), so a take the light or its timing spoiled
            counts for its share only.
    """

    source: str
    fps: float
    steps: list[StepFit]
    rest_face: np.ndarray
    rest_landmarks: np.ndarray
    rest_scores: np.ndarray
    score_names: list[str]
    pose_model: np.ndarray
    basis: np.ndarray
    basis_steps: list[str]
    noise: np.ndarray
    curves: dict[str, dict]
    warnings: list[str] = field(default_factory=list)
    more_takes: list[ActorCalibration] = field(default_factory=list)

    @property
    def takes(self) -> list[ActorCalibration]:
        """This take's calibration and each of :attr:`more_takes`."""
        return [self, *self.more_takes]

    @classmethod
    def together(cls, calibrations: list[ActorCalibration]) -> ActorCalibration:
        """One calibration of several takes of one actor: the first, the others as its
        :attr:`more_takes`."""
        first, *more = calibrations
        if any(c.score_names != first.score_names for c in more):
            raise CaptureError("calibrations of several takes must come from the same tracker's scores")
        return dataclasses.replace(first, more_takes=[*first.more_takes, *(t for c in more for t in c.takes)])

    def to_json(self) -> dict:
        r = lambda a, d=4: np.round(np.asarray(a, np.float64), d).tolist()  # noqa: E731
        return {
            "format": FORMAT,
            "source": self.source,
            "fps": self.fps,
            "curves": self.curves,
            "steps": [{"name": s.name, "found": s.found, "frames": s.frames, "hold": s.hold, "match": s.match,
                       "before": s.before, "after": s.after} for s in self.steps],
            "warnings": self.warnings,
            "rest": {"scores": dict(zip(self.score_names, r(self.rest_scores), strict=True)),
                     "landmarks": r(self.rest_landmarks), "face": r(self.rest_face)},
            "pose_model": r(self.pose_model, 5),
            "basis": {name: r(row, 5) for name, row in zip(self.basis_steps, self.basis, strict=True)},
            "noise": dict(zip(self.basis_steps, r(self.noise), strict=True)),
            **({"more_takes": [t.to_json() for t in self.more_takes]} if self.more_takes else {}),
        }

    def save(self, path: str | os.PathLike) -> None:
        """actor.json: what a user reads and edits first, one item a line; then the learned
        arrays, one line each; then each of :attr:`more_takes` laid out the same way."""
        write_text_atomic(path, _layout(self.to_json()) + "\n")

    @classmethod
    def from_json(cls, data: dict, where: str = "calibration") -> ActorCalibration:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise CaptureError(f"{where}: not an actor calibration (no \"format\": \"{FORMAT}\")")
        try:
            names = list(data["rest"]["scores"])
            basis_steps = list(data["basis"])
            pose_model = np.asarray(data["pose_model"], np.float32)
            basis = np.asarray([data["basis"][n] for n in basis_steps], np.float32).reshape(len(basis_steps),
                                                                                             pose_model.shape[1])
            steps = [StepFit(s["name"], bool(s["found"]), _pair(s.get("frames")), _pair(s.get("hold")),
                             s.get("match"), dict(s.get("before", {})), dict(s.get("after", {})))
                     for s in data["steps"]]
            curves = {str(k): {"source": str(v.get("source", "expressions")), "gain": float(v["gain"]),
                               "offset": float(v["offset"]), "steps": list(v["steps"]),
                               **({"explained_by": {str(s): float(b) for s, b in v["explained_by"].items()}}
                                  if "explained_by" in v else {}),
                               **({"score": {f: float(v["score"][f]) for f in ("share", "gain", "offset")}}
                                  if "score" in v else {})}
                      for k, v in data["curves"].items()}
            more = [cls.from_json(t, f"{where} (take {k + 2})") for k, t in enumerate(data.get("more_takes", []))]
            out = cls(source=str(data.get("source", "")), fps=float(data.get("fps", 30.0)), steps=steps,
                      rest_face=np.asarray(data["rest"]["face"], np.float32),
                      rest_landmarks=np.asarray(data["rest"]["landmarks"], np.float32),
                      rest_scores=np.asarray(list(data["rest"]["scores"].values()), np.float32),
                      score_names=names, pose_model=pose_model,
                      basis=basis, basis_steps=basis_steps,
                      noise=np.asarray([data["noise"][n] for n in basis_steps], np.float32),
                      curves=curves, warnings=list(data.get("warnings", [])), more_takes=more)
        except (KeyError, TypeError, ValueError) as exc:
            raise CaptureError(f"{where}: a damaged actor calibration ({type(exc).__name__}: {exc})") from None
        bad = [k for k, v in out.curves.items() if v["source"] not in SOURCES]
        if bad:
            raise CaptureError(f"{where}: curve {bad[0]}'s source must be one of {', '.join(SOURCES)}")
        if any(t.score_names != out.score_names for t in more):
            raise CaptureError(f"{where}: its takes were read by different trackers (their scores differ)")
        if out.rest_landmarks.shape != (478, 3) or out.rest_face.shape != (478, 3):
            raise CaptureError(f"{where}: a damaged actor calibration (its rest is not 478 landmarks)")
        for name, c in out.curves.items():
            unknown = [s for s in (*c["steps"], *c.get("explained_by", {})) if s not in out.basis_steps]
            if unknown:
                raise CaptureError(f"{where}: curve {name} names steps the calibration lacks: {', '.join(unknown)}")
        return out

    @classmethod
    def load(cls, path: str | os.PathLike) -> ActorCalibration:
        try:
            with open(path, encoding="utf-8") as f:
                data = json.load(f)
        except OSError as exc:
            raise CaptureError(f"--calibration {path}: cannot read it ({exc.strerror or exc})") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CaptureError(f"--calibration {path}: not JSON ({exc})") from None
        return cls.from_json(data, f"--calibration {path}")


def _layout(data: dict) -> str:
    """One take's JSON as actor.json lays it out (:meth:`ActorCalibration.save`), with its
    ``more_takes`` nested, each laid out the same way."""
    more = [_layout(t) for t in data.pop("more_takes", [])]
    learned = {k: data.pop(k) for k in LEARNED}
    head = json.dumps(data, indent=1)
    tail = [f" {json.dumps(k)}: {json.dumps(v, separators=(',', ':'))}" for k, v in learned.items()]
    if more:
        tail.append(' "more_takes": [\n' + ",\n".join(more) + "\n ]")
    return f"{head[:-2]},\n" + ",\n".join(tail) + "\n}"


def _pair(value) -> tuple[int, int] | None:
    return None if value is None else (int(value[0]), int(value[1]))

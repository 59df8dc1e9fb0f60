"""The range-of-motion (ROM) protocol: the expressions an actor records once per shoot,
each held about a second and back to neutral, in this order (docs/calibration.md shows
them as a list and an illustrated sheet).

Each step names the ARKit curves it shows and at what weight: what the actor's full
expression means on the ARKit scale. A calibration learns how this actor's face shows each
step (:mod:`capture2face.calibration.learn`); a synthetic ROM take performs the steps at
exactly these weights (``capture2face synth --rom``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.topology import ARKIT_NAMES


@dataclass(frozen=True)
class Step:
    """One expression of the protocol.

    Attributes:
        name: short id (``jaw_open``), used in actor.json and warnings.
        instruction: what the actor is told, as printed on the sheet.
        targets: ARKit name -> weight the expression has at its full hold.
    """

    name: str
    instruction: str
    targets: dict[str, float]


def _both(stem: str, weight: float = 1.0) -> dict[str, float]:
    return {stem + "Left": weight, stem + "Right": weight}


PROTOCOL: tuple[Step, ...] = (
    Step("brows_up", "Raise both eyebrows as high as you can", {"browInnerUp": 1.0, **_both("browOuterUp")}),
    Step("frown", "Frown: pull the brows down and together", _both("browDown")),
    Step("eyes_closed", "Close both eyes, relaxed, not squeezed", _both("eyeBlink")),
    Step("eyes_wide", "Open the eyes wide, brows still", _both("eyeWide")),
    Step("squint", "Squint: narrow the eyes from below", _both("eyeSquint")),
    Step("look_left", "Look to your left, head still, lids relaxed",
         {"eyeLookOutLeft": 1.0, "eyeLookInRight": 1.0}),
    Step("look_right", "Look to your right, head still, lids relaxed",
         {"eyeLookInLeft": 1.0, "eyeLookOutRight": 1.0}),
    Step("look_up", "Look up, head still, lids relaxed", _both("eyeLookUp")),
    Step("look_down", "Look down, head still, lids relaxed", _both("eyeLookDown")),
    Step("jaw_open", "Open the jaw wide, lips relaxed", {"jawOpen": 1.0}),
    Step("jaw_left", "Jaw to your left, lips closed", {"jawLeft": 1.0}),
    Step("jaw_right", "Jaw to your right, lips closed", {"jawRight": 1.0}),
    Step("jaw_forward", "Push the jaw forward", {"jawForward": 1.0}),
    Step("smile", "Wide smile, as broad as you can", {**_both("mouthSmile"), **_both("cheekSquint", 0.5)}),
    Step("frown_mouth", "Pull the mouth corners down", _both("mouthFrown")),
    Step("stretch", "Stretch the lips sideways and down, as in 'eek'", _both("mouthStretch")),
    Step("pucker", "Pucker: a kiss, lips pushed forward", {"mouthPucker": 1.0}),
    Step("funnel", "Funnel: lips rounded as in 'oo', a little open", {"mouthFunnel": 1.0, "jawOpen": 0.2}),
    Step("lips_pressed", "Press the lips together", _both("mouthPress")),
    Step("lips_rolled_in", "Roll both lips in over the teeth", {"mouthRollLower": 1.0, "mouthRollUpper": 1.0}),
    Step("lower_lip_down", "Pull the lower lip down, showing the lower teeth", _both("mouthLowerDown")),
    Step("upper_lip_up", "Raise the upper lip, showing the upper teeth", _both("mouthUpperUp")),
    Step("mouth_left", "Move the closed mouth to your left", {"mouthLeft": 1.0}),
    Step("mouth_right", "Move the closed mouth to your right", {"mouthRight": 1.0}),
    Step("chin_up", "Push the lower lip and chin up (a pout)", {"mouthShrugLower": 1.0, "mouthShrugUpper": 0.5}),
    Step("cheek_puff", "Puff the cheeks out", {"cheekPuff": 1.0}),
    Step("sneer", "Sneer: wrinkle the nose", _both("noseSneer")),
)
STEP_NAMES = tuple(s.name for s in PROTOCOL)

# Timing of a take, seconds: the neutral at the start, then per step: ease in, hold, ease
# out, neutral. About 42 s for the 27 steps (the synthetic take; a real take may differ).
LEAD_NEUTRAL, EASE, HOLD, GAP = 1.5, 0.2, 0.7, 0.4


def target_matrix(names: list[str] | tuple[str, ...] = ARKIT_NAMES,
                  steps: tuple[Step, ...] = PROTOCOL) -> np.ndarray:
    """(C, K) float64: column k is step k's weight of each of ``names`` (0 where it has none)."""
    col = {n: i for i, n in enumerate(names)}
    out = np.zeros((len(names), len(steps)))
    for k, step in enumerate(steps):
        for name, weight in step.targets.items():
            if name in col:
                out[col[name], k] = weight
    return out


def step_amounts(fps: float, steps: tuple[Step, ...] = PROTOCOL) -> np.ndarray:
    """(F, K) float64 each step's amount (0..1) per frame of a take performed on the
    protocol's timing: smooth eases, one step at a time."""
    per_step = 2 * EASE + HOLD + GAP
    frames = int(round((LEAD_NEUTRAL + per_step * len(steps)) * fps))
    t = np.arange(frames) / fps
    out = np.zeros((frames, len(steps)))
    for k in range(len(steps)):
        start = LEAD_NEUTRAL + k * per_step
        rise = np.clip((t - start) / EASE, 0.0, 1.0)
        fall = np.clip((start + EASE + HOLD + EASE - t) / EASE, 0.0, 1.0)
        u = np.minimum(rise, fall)
        out[:, k] = u * u * (3.0 - 2.0 * u)
    return out

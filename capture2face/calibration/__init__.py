"""Per-actor calibration from a range-of-motion take (docs/calibration.md): the protocol,
finding its steps in a tracked take, learning the actor's own expressions, and the
calibrated ARKit curves of any clip of that actor."""

from capture2face.calibration.learn import calibrate, calibrated_curves, calibration_rest
from capture2face.calibration.model import ActorCalibration, StepFit
from capture2face.calibration.protocol import PROTOCOL, STEP_NAMES, Step

__all__ = ["PROTOCOL", "STEP_NAMES", "ActorCalibration", "Step", "StepFit", "calibrate", "calibrated_curves",
           "calibration_rest"]

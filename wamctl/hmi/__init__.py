"""Gaze human-machine interface (thesis chapter 6, issue 7): from the gaze tracker to hand commands and the hand.

* :mod:`wamctl.hmi.gaze`: samples, their classification, the image geometry, the protocol of a gaze source (the
  sources themselves are devices: :mod:`wamctl.backends.gaze`);
* :mod:`wamctl.hmi.signal`: causal per-sample processing (blinks, corrupt samples, MA/WMA, Kalman on the angle);
* :mod:`wamctl.hmi.strategy`: four-directional and vector control, velocity profiles, the controller;
* :mod:`wamctl.hmi.kinematics`: tool-point kinematics of the palm-down hand and the differential IK step;
* :mod:`wamctl.hmi.scene`: table plane, workspace box, scene camera, command frame -> table plane;
* :mod:`wamctl.hmi.gripper`: the simulated BarrettHand;
* :mod:`wamctl.hmi.arm`: :class:`~wamctl.hmi.arm.HandArm`, the arm's driver, tick by tick on an open backend;
* :mod:`wamctl.hmi.policy`: where a virtual subject looks to steer the hand (the closed loop of a simulated trial).

Data flow, one way: source -> :class:`GazeController` (filters, strategy, blink commands, watchdog) ->
:class:`HandCommand` -> :class:`~wamctl.hmi.arm.HandArm`. Pixels say ``px``, times ``_s``, speeds ``_m_s``,
angles are radians.

May import: control, model, io, errors. Never specs, backends, analysis, experiments, report or the CLI (the
backend a :class:`~wamctl.hmi.arm.HandArm` drives is handed to it).
"""

from wamctl.hmi.gaze import GazeFlag, GazeSample, GazeSource
from wamctl.hmi.signal import (
    BlinkEvent,
    BlinkRemover,
    CorruptSampleRemover,
    KalmanAngleFilter,
    MovingAverageFilter,
    SampleRateEstimator,
    VoluntaryBlinkDetector,
    WeightedMovingAverageFilter,
)
from wamctl.hmi.strategy import (
    EventKind,
    FourDirectionalStrategy,
    GazeController,
    GazeEvent,
    HandCommand,
    Hold,
    Motion,
    VectorStrategy,
    VelocityProfile,
    cubic_profile,
    drive,
    dual_profile,
    make_gaze_controller,
    single_profile,
)

__all__ = [
    "BlinkEvent", "BlinkRemover", "CorruptSampleRemover", "EventKind", "FourDirectionalStrategy", "GazeController",
    "GazeEvent", "GazeFlag", "GazeSample", "GazeSource", "HandCommand", "Hold", "KalmanAngleFilter", "Motion",
    "MovingAverageFilter", "SampleRateEstimator", "VectorStrategy", "VelocityProfile", "VoluntaryBlinkDetector",
    "WeightedMovingAverageFilter", "cubic_profile", "drive", "dual_profile", "make_gaze_controller",
    "single_profile",
]

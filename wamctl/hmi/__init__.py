"""Gaze human-machine interface (thesis chapter 6, issue 7): from the gaze tracker to hand commands.

* :mod:`wamctl.hmi.gaze`: samples, their classification, the image geometry, the protocol of a gaze source (the
  sources themselves are devices: :mod:`wamctl.backends.gaze`);
* :mod:`wamctl.hmi.signal`: causal per-sample processing (blinks, corrupt samples, MA/WMA, Kalman on the angle);
* :mod:`wamctl.hmi.strategy`: four-directional and vector control, velocity profiles, the controller.

Data flow, one way: source -> :class:`GazeController` (filters, strategy, blink commands, watchdog) ->
:class:`HandCommand` for the arm. Pixels say ``px``, times ``_s``, speeds ``_m_s``, angles are radians.
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

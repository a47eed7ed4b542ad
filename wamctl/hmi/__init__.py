"""Gaze human-machine interface (thesis chapter 6, issue 7): from the gaze tracker to hand commands.

* :mod:`wamctl.hmi.gaze`: samples, the serial line format, and the sources (serial, replay, virtual subject);
* :mod:`wamctl.hmi.signal`: causal per-sample processing (blinks, corrupt samples, MA/WMA, Kalman on the angle);
* :mod:`wamctl.hmi.strategy`: four-directional and vector control, velocity profiles, the controller.

Data flow, one way: source -> :class:`GazeController` (filters, strategy, blink commands, watchdog) ->
:class:`HandCommand` for the arm. Pixels say ``px``, times ``_s``, speeds ``_m_s``, angles are radians.
"""

from wamctl.hmi.gaze import (
    BlinkTruth,
    GazeFlag,
    GazeLineDecoder,
    GazeSample,
    GazeSource,
    ReplayGazeSource,
    SerialGazeSource,
    VirtualSubject,
    format_line,
    parse_line,
    read_gaze_csv,
    write_gaze_csv,
)
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
    make_controller,
    single_profile,
)

__all__ = [
    "BlinkEvent", "BlinkRemover", "BlinkTruth", "CorruptSampleRemover", "EventKind", "FourDirectionalStrategy",
    "GazeController", "GazeEvent", "GazeFlag", "GazeLineDecoder", "GazeSample", "GazeSource", "HandCommand",
    "Hold", "KalmanAngleFilter", "Motion", "MovingAverageFilter", "ReplayGazeSource", "SampleRateEstimator",
    "SerialGazeSource", "VectorStrategy", "VelocityProfile", "VirtualSubject", "VoluntaryBlinkDetector",
    "WeightedMovingAverageFilter", "cubic_profile", "drive", "dual_profile", "format_line", "make_controller",
    "parse_line", "read_gaze_csv", "single_profile", "write_gaze_csv",
]

"""The sample-rate estimator on bursty arrival stamps (a loaded machine's reader returns several frames a
millisecond apart): with an even count of intervals split between bursts and periods, the median falls between
the two groups and no interval is within 0.5-1.5 times it. The estimator divided by zero there (it crashed a
``via: pty`` replay in tests/hmi/test_gaze_e2e.py under load, 1 run in 10); it keeps its last estimate."""

from __future__ import annotations

import pytest

from wamctl.hmi.gaze import GazeSample
from wamctl.hmi.signal import SampleRateEstimator


def test_no_interval_near_the_median_keeps_the_last_rate():
    est = SampleRateEstimator(min_intervals=5)
    t_s, rates = 100.0, []
    for dt_s in (0.0, 0.001, 0.001, 0.001, 0.033, 0.033, 0.033):  # intervals: 3 x 1 ms, then 3 x 33 ms
        t_s += dt_s
        rates.append(est.update(GazeSample(t_s, 384.0, 288.0)))
    # 5 intervals (1, 1, 1, 33, 33 ms): median 1 ms, the three 1 ms intervals typical; the 6th: median 17 ms, none
    assert rates[5] == pytest.approx(1000.0)
    assert rates[6] == pytest.approx(1000.0)

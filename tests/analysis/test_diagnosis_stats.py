"""The diagnosis' held-out nested F-test on autocorrelated residuals (what every "effect found" rests on).

A residual of a 500 Hz log is strongly autocorrelated (filters, slow model errors); counted as independent
samples, any irrelevant regressor would look significant. Tolerances chosen before running: the integrated
autocorrelation time of an AR(1) with phi = 0.9 is (1 + phi) / (1 - phi) = 19, recovered within 30 %; under the
null, the rejection rate at alpha = 0.05 over 400 trials at most 0.08 (nominal 0.05 plus ~3 binomial SDs).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from wamctl.analysis.diagnosis.stats import effective_tau, nested_test

PHI = 0.9


def ar1(rng: np.random.Generator, n: int, phi: float = PHI) -> np.ndarray:
    return lfilter([1.0], [1.0, -phi], rng.standard_normal(n))


def test_integrated_autocorrelation_time_of_an_ar1():
    rng = np.random.default_rng(1)
    taus = [effective_tau(ar1(rng, 4000)) for _ in range(20)]
    assert abs(np.median(taus) / ((1 + PHI) / (1 - PHI)) - 1) < 0.3


def test_an_irrelevant_regressor_is_not_significant_on_autocorrelated_residuals():
    """Null: the 'effect' is a regressor unrelated to the residual, its coefficient fitted on training data of
    its own and applied to held-out data, as the diagnosis does."""
    rng = np.random.default_rng(2)
    n, trials, rejected = 2000, 400, 0
    for _ in range(trials):
        r_train, x_train = ar1(rng, n), ar1(rng, n)
        b = float(x_train @ r_train / (x_train @ x_train))
        e0, x = ar1(rng, n), ar1(rng, n)
        res = nested_test(e0, e0 - b * x, p_extra=1, k1=1, min_effect=0.0)
        rejected += res["p_value"] < 0.05
    assert rejected / trials <= 0.08, f"{rejected} of {trials} rejected at alpha 0.05"

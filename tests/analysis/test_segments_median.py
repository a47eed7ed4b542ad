"""The friction map's stage loops' median (segments._median) is numpy's median, number for number."""

from __future__ import annotations

import warnings

import numpy as np

from wamctl.analysis.friction_id.segments import _median


def test_median_is_numpys_median_on_random_input():
    rng = np.random.default_rng(3)
    for n in [*range(1, 12), 100, 101, 5000, 5001]:
        for k in range(12):
            x = rng.normal(size=n) * 10 ** rng.uniform(-5, 5)
            if k % 3 == 0:
                x = np.round(x, 1)             # ties, as quantised positions give
            if k == 5:
                x[rng.integers(n)] = np.nan
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                want = float(np.median(x))
            got = _median(x)
            assert (np.isnan(want) and np.isnan(got)) or got == want, (n, k, got, want)

"""The diagnosis' filter evaluated at a run's samples only (Signals.smooth_at), the signals kept on a grid, the
whiteness test: each against the plain computation it stands in for."""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.diagnosis.signals import GridSignal, Signals, smooth
from wamctl.analysis.diagnosis.stats import whiteness_p

N = 20000
DT = 0.002
WINDOW, GAUSS = 15, 4.0


@pytest.fixture(scope="module")
def run():
    rng = np.random.default_rng(7)
    t = np.arange(N) * DT
    q = np.cumsum(rng.normal(0, 1e-3, (N, 7)), axis=0) + np.sin(t)[:, None]
    sig = Signals(t, DT, WINDOW, GAUSS, q, q, q, q, q, np.ones((N, 7), bool), [0])
    return sig, q, rng


def _reference(x: np.ndarray, idx: np.ndarray, shift: float, deriv: int = 0) -> np.ndarray:
    """The filter at the full rate, read at ``idx + shift`` (linear interpolation between samples)."""
    full = smooth(x, WINDOW, GAUSS, deriv, DT)
    pos = idx + shift
    if full.ndim == 1:
        return np.interp(pos, np.arange(N), full)
    return np.column_stack([np.interp(pos, np.arange(N), c) for c in full.T])


@pytest.mark.parametrize("layout", ["sparse", "stretches", "dense"])
@pytest.mark.parametrize("shift", [0.0, 2.0, -3.4])
def test_smooth_at_is_the_full_rate_filter_read_at_the_samples(run, layout, shift, monkeypatch):
    """Far-apart samples (one window each), stretches (a convolution over them) and most of the run (the full
    rate) all give the filter of the full-rate feature at those samples, for arrays, functions of sample
    indices, and functions of a source signal's values."""
    from wamctl.analysis.diagnosis import signals

    sig, q, rng = run
    used = []
    for name in ("_smooth_windows", "_smooth_stretches", "_interp_rows"):
        f = getattr(signals, name)
        monkeypatch.setattr(signals, name, lambda *a, f=f, name=name, **k: used.append(name) or f(*a, **k))
    inner = np.arange(200, N - 200)
    if layout == "sparse":
        idx = np.sort(rng.choice(inner[::60], 150, replace=False))
    elif layout == "stretches":
        idx = np.concatenate([np.arange(s, s + rng.integers(5, 120)) for s in range(300, N - 400, 900)])
    else:
        idx = inner[::3]
    x = q[:, 2].copy()

    def feature(v):
        return np.column_stack([np.sin(40 * v), v > 0.5])

    for deriv in (0, 2):
        np.testing.assert_allclose(sig.smooth_at(q, idx, shift, deriv), _reference(q, idx, shift, deriv),
                                   rtol=1e-9, atol=1e-9 * np.abs(q).max())
    want = _reference(feature(x), idx, shift)
    np.testing.assert_allclose(sig.smooth_at(lambda p: feature(x[p]), idx, shift), want, atol=1e-12)
    for _ in range(2):          # the second time from the windows kept
        np.testing.assert_allclose(sig.smooth_at(feature, idx, shift, source=(("x", 2), x)), want, atol=1e-12)
    np.testing.assert_allclose(sig.at("q", idx, shift, joint=4), _reference(q[:, 4], idx, shift),
                               rtol=1e-9, atol=1e-12)
    path = {"sparse": "_smooth_windows", "stretches": "_smooth_stretches", "dense": "_interp_rows"}[layout]
    assert set(used) == {path}


def test_grid_signal_interpolates_between_its_samples():
    grid = np.r_[np.arange(0, 1000, 40), 999]
    values = np.column_stack([np.cos(grid / 100.0), grid ** 2.0])
    g = GridSignal(grid, values)
    pos = np.array([0, 17, 40.5, 998.2, 999])
    np.testing.assert_array_equal(g.at(pos, 0), np.interp(pos, grid, values[:, 0]))
    np.testing.assert_array_equal(g[np.array([3, 500]), 1], np.interp([3, 500], grid, values[:, 1]))
    assert g.at(np.array([-5.0, 2000.0]), 1).tolist() == [0.0, 999.0 ** 2]      # held beyond the grid
    np.testing.assert_array_equal(g[:, 0], np.interp(np.arange(1000), grid, values[:, 0]))


def test_whiteness_is_statsmodels_ljung_box():
    """The Ljung-Box p-value written out here against statsmodels' (an outside reference)."""
    from statsmodels.stats.diagnostic import acorr_ljungbox

    rng = np.random.default_rng(3)
    for ar in (0.0, 0.3, 0.8):
        e = np.zeros(900)
        w = rng.normal(size=900)
        for i in range(1, 900):
            e[i] = ar * e[i - 1] + w[i]
        e[::11] = np.nan
        x = e[np.isfinite(e)][::2]
        want = float(acorr_ljungbox(x - x.mean(), lags=[10], return_df=True)["lb_pvalue"].iloc[0])
        assert whiteness_p(e, 2) == pytest.approx(want, rel=1e-9, abs=1e-300)
    assert np.isnan(whiteness_p(np.ones(100), 1))


@pytest.mark.parametrize("fortran", [False, True])
def test_a_quantised_source_is_evaluated_once_per_distinct_value(run, fortran):
    """An encoder-quantised source: its windows' feature is evaluated on the distinct counts only and read back by
    index; the numbers are the same as the feature evaluated on every window value (identical, not close)."""
    from wamctl.analysis.diagnosis import signals

    sig, q, rng = run
    sig._memo.clear()
    x = np.round(q[:, 3] / 2e-3) * 2e-3                 # counts of 2 mrad: a few hundred distinct values
    idx = np.sort(rng.choice(np.arange(200, N - 200)[::80], 200, replace=False))
    seen = []

    def feature(v):
        seen.append(len(v))
        out = np.column_stack([np.sin(40 * v), np.cos(7 * v), v ** 2])
        return np.asfortranarray(out) if fortran else out

    for _ in range(signals.FACTOR_AFTER_USES):           # the first features of a source evaluated directly
        seen.clear()
        got = sig.smooth_at(feature, idx, 1.0, source=(("x", 3), x), quantised=True)
    assert seen == [len(np.unique(x))] and seen[0] < len(idx) * 10     # once, on the distinct values
    k = sig.kernel()
    first = 1 - len(k) // 2
    want = signals._smooth_windows(feature, 3, idx, k, first, N,
                                   [x[np.clip(idx[None, :] + first + np.arange(len(k))[:, None], 0, N - 1).ravel()]])
    np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(got, _reference(np.asarray(feature(x)), idx, 1.0), atol=1e-12)

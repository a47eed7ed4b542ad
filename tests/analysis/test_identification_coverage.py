"""`wamctl identify`'s intervals hold the truth as often as they say, and its held-out check does not call a correct
declared arm worse (issue 27 item 3).

The runs are tests/analysis/test_identification_wam4.py's (a sum of sines on a wam4 whose torque is written by
pinocchio, friction 1.3x the declared, white torque and position noise; fit and held-out trajectories of seeds
100 + 2 i and 101 + 2 i, as benchmarks/bench_identify_coverage.py). Before this change, on the declared arm: 77 %
of the consistent estimate's 95 % intervals held the truth over 20 seeds (the SDP solver stopped up to 3.6
posterior standard errors from its minimum, and the sandwich, estimated from some 30 independent stretches for 40
parameters, was too small in the directions the data see least), 88 % of the data-only ones, and the held-out check
said `worse` on 7 of 20 seeds (4 of the first 5). Thresholds set before looking at the new figures: >= 93 % (the
data-only intervals) and >= 90 % (the consistent ones) over the 240 determined parameters of six seeds, the errors'
RMS at most 1.15 standard errors; `no_worse` or `better` on every one of five seeds of the declared arm, `better`
on every one of three of the perturbed one.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import test_identification_wam4 as W4

from wamctl.analysis.identification.estimator import effective_blocks, leverage_adjusted, shrinkage_intensity


def _fit(root, i: int, scale: float):
    from wamctl.experiments.identify import held_out_check, identify

    fit = W4.write_run(root / f"fit{i}", scale, 100 + 2 * i)
    held = W4.write_run(root / f"held{i}", scale, 101 + 2 * i)
    logging.disable(logging.WARNING)
    try:
        est, validation, _ = identify([fit], [held])
    finally:
        logging.disable(logging.NOTSET)
    check = held_out_check(validation, sorted({j for rr in est.rows_ for j in rr.joints}))
    truth = est.base_.of(W4._truth_pi(scale))
    ok = est.identified_
    z = {"data": ((est.beta_wls_ - truth) / est.se_)[ok], "consistent": ((est.beta_ - truth) / est.se_post_)[ok]}
    crit = {"data": est.critical_values("wls")[ok], "consistent": est.critical_values()[ok]}
    lo, hi = est.intervals()
    inside = ((truth >= lo) & (truth <= hi))[ok]
    return {"z": z, "crit": crit, "inside": inside, "verdict": check["verdict"], "ratio": check["ratio"],
            "widths": est.prior_widths_}


@pytest.fixture(scope="module")
def declared_arm(tmp_path_factory):
    root = tmp_path_factory.mktemp("cov")
    return [_fit(root, i, 0.0) for i in range(6)]


def test_intervals_hold_the_truth_on_the_declared_arm(declared_arm):
    for path, want in (("data", 0.93), ("consistent", 0.90)):
        z = np.concatenate([f["z"][path] for f in declared_arm])
        crit = np.concatenate([f["crit"][path] for f in declared_arm])
        cover = float(np.mean(np.abs(z) <= crit))
        rms = float(np.sqrt(np.mean(z ** 2)))
        print(path, "coverage", round(cover, 3), "of", len(z), "RMS error / SE", round(rms, 3))
        assert cover >= want, (path, cover)
        assert rms <= 1.15, (path, rms)
    # intervals() is what the table prints: the same coverage as counted above
    inside = np.concatenate([f["inside"] for f in declared_arm])
    assert np.mean(inside) >= 0.90


def test_held_out_check_does_not_call_the_declared_arm_worse(declared_arm):
    verdicts = [f["verdict"] for f in declared_arm[:5]]
    print(verdicts, [{j: round(r, 4) for j, r in f["ratio"].items()} for f in declared_arm[:5]])
    assert all(v in ("no_worse", "better") for v in verdicts), verdicts


def test_the_declared_arm_keeps_its_prior(declared_arm):
    """The data agree with the declared links: no joint's prior is widened (prior_widths, type-II maximum
    likelihood floored at the declared accuracy)."""
    widths = np.array([f["widths"] for f in declared_arm])
    print(np.round(widths, 3))
    assert widths.max() <= 1.2, widths


def test_a_perturbed_arm_widens_its_prior_and_its_intervals_hold_the_truth(tmp_path):
    """Links 2-4 25-35 % heavier, their COMs 1.5 cm off (seeds 0-3): the held-out check says `better` on every
    seed, and the data widen the prior of the perturbed links, so that the consistent intervals hold the truth
    for >= 90 % of the 160 determined base parameters, errors' RMS <= 1.2 standard errors. (Measured when written:
    147/160 = 0.919, widths of joints 2-4 up to x3; with the prior fixed at the declared 30 %: 131/160 = 0.819,
    the errors' RMS 1.58 SE: a prior 30 % wide that a link's truth lies outside biases the estimate toward the
    declared arm; over 20 seeds, benchmarks/bench_identify_coverage.py --scale 1: 95.0 % against 86.9 %.)"""
    fits = [_fit(tmp_path, i, 1.0) for i in range(4)]
    assert [f["verdict"] for f in fits] == ["better"] * 4, [f["verdict"] for f in fits]
    widths = np.array([f["widths"] for f in fits])
    z = np.concatenate([f["z"]["consistent"] for f in fits])
    crit = np.concatenate([f["crit"]["consistent"] for f in fits])
    cover, rms = float(np.mean(np.abs(z) <= crit)), float(np.sqrt(np.mean(z ** 2)))
    print(np.round(widths, 2), "coverage", round(cover, 3), "of", len(z), "RMS error / SE", round(rms, 3))
    assert np.all(widths[:, 1:].max(axis=1) > 1.5), widths
    assert cover >= 0.90 and rms <= 1.2, (cover, rms)


def test_leverage_adjusted_residuals_restore_the_error_variance():
    """White errors, least squares with 30 parameters on 300 rows in blocks of 20: the raw residuals' sum of
    squares is (n - p) sigma^2 on average, the adjusted ones' n sigma^2 (to 2 %, 400 draws)."""
    rng = np.random.default_rng(5)
    n, p = 300, 30
    X = rng.normal(size=(n, p)) * np.linspace(0.2, 3.0, n)[:, None]      # uneven leverage along the record
    Q, _ = np.linalg.qr(X)
    sample = np.arange(n)
    raw, adj = [], []
    for _ in range(400):
        u = rng.normal(size=n)
        e = u - Q @ (Q.T @ u)
        raw.append(e @ e)
        ea = leverage_adjusted(Q, e, sample, 20)
        adj.append(ea @ ea)
    assert abs(np.mean(raw) / (n - p) - 1) < 0.03
    assert abs(np.mean(adj) / n - 1) < 0.02, np.mean(adj) / n


def test_effective_blocks_counts_the_blocks_a_parameter_rests_on():
    block = np.repeat(np.arange(10), 5)
    even = np.ones((50, 2))
    even[:, 1] = 0.0
    even[:5, 1] = 1.0       # parameter 2: only the first block's rows move it
    np.testing.assert_allclose(effective_blocks(even, block), [10.0, 1.0])


def test_shrinkage_intensity_is_ledoit_and_wolfs():
    sk = pytest.importorskip("sklearn.covariance")
    rng = np.random.default_rng(2)
    X = rng.normal(size=(30, 12)) @ np.diag(np.linspace(0.5, 2.0, 12))
    np.testing.assert_allclose(shrinkage_intensity(X), sk.ledoit_wolf_shrinkage(X, assume_centered=True),
                               rtol=1e-10)

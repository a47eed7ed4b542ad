"""Figures of merit of an identification (wamctl.analysis.identification.metrics): relative torque error per
trajectory with its interval, moves from the prior in prior standard deviations, Sousa-Cortesao checks."""

from types import SimpleNamespace

import numpy as np
import pytest

from wamctl.analysis.identification.base import base_parameters, standard_vector
from wamctl.analysis.identification.estimator import PRIOR_WEIGHT, prior_scale
from wamctl.analysis.identification.metrics import com_boxes, physical_checks, prior_moves, prior_sd, relative_errors
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.model.friction import FrictionModel


class _Rows(SimpleNamespace):
    pass


def _fake_est(scale=0.9, noise=0.0):
    """An 'estimator' whose identified model predicts scale x the measured torque (+ noise), the nominal 0.5 x."""
    rng = np.random.default_rng(0)
    n = 2000
    t = np.arange(n) * 0.01
    y = np.concatenate([np.sin(2 * np.pi * 0.3 * t + j) * (j + 1) for j in range(7)])
    k = np.tile(np.arange(n), 7)
    j = np.repeat(np.arange(7), n)
    rows = _Rows(source="/x/run-a", reach_s=0.05, dt_s=0.01)

    def predict(rr, which, mask=None):
        sel = np.ones(len(y), bool) if mask is None else mask[k]
        p = (scale * y + noise * rng.standard_normal(len(y))) if which == "identified" else 0.5 * y
        return p[sel], y[sel], j[sel], k[sel]
    return SimpleNamespace(predict=predict, rows_=[rows]), rows, n


def test_relative_error_is_the_norm_ratio_with_an_interval_around_it():
    est, rows, n = _fake_est(0.9)
    out = relative_errors(est, [rows], [np.arange(n) >= 1500])
    held = out["held_out"][0]
    assert held["identified"] == pytest.approx(0.1, abs=1e-12)      # ||y - 0.9 y|| / ||y||
    assert held["nominal"] == pytest.approx(0.5, abs=1e-12)
    assert held["samples"] == 500 and held["identified_ci95"] == pytest.approx([0.1, 0.1], abs=1e-12)
    assert out["in_sample"][0]["samples"] == n and out["published_held_out_pct"] == [6.7, 8.5]
    est, rows, n = _fake_est(1.0, noise=0.3)
    held = relative_errors(est, [rows], [None])["held_out"][0]
    lo, hi = held["identified_ci95"]
    assert lo < held["identified"] < hi and hi - lo < 0.3 * held["identified"]


def test_prior_sd_is_the_estimators_prior_on_the_base_parameters():
    base = base_parameters()
    pi0 = standard_vector(WamDynamics(), FrictionModel.table_4_1())
    s = prior_scale(pi0)
    Ks = base.matrix * s
    # the estimator's prior precision (delta units): PRIOR_WEIGHT on K diag(s)'s row space, 1 on its null space
    _, sv, Vt = np.linalg.svd(Ks, full_matrices=True)
    r = int(np.sum(sv > 1e-10 * sv[0]))
    Pw = np.vstack([np.sqrt(PRIOR_WEIGHT) * Vt[:r], Vt[r:]])
    cov = Ks @ np.linalg.inv(Pw.T @ Pw) @ Ks.T
    est = SimpleNamespace(base_=base, pi_declared_=pi0)
    np.testing.assert_allclose(prior_sd(est), np.sqrt(np.diag(cov)), rtol=1e-9)
    beta0 = base.of(pi0)
    ident = np.ones(base.n_base, bool)
    ident[3] = False
    est = SimpleNamespace(base_=base, pi_declared_=pi0, beta_=beta0 + 2.0 * prior_sd(est), identified_=ident)
    moves = prior_moves(est)
    assert moves[0]["moved_prior_sd"] == pytest.approx(2.0, rel=1e-12) and moves[3]["moved_prior_sd"] is None


def test_datasheet_passes_the_physical_checks_and_a_misplaced_com_or_mass_does_not():
    ds = P.LinkParameters.datasheet()
    ok = physical_checks(ds)
    assert ok["ok"] and not ok["enforced"] and ok["total_mass"]["relative"] == 0.0
    lo, hi = com_boxes()[2]                     # link 3: the upper arm, 0.55 m along y3
    assert lo[1] < 0 < 0.55 < hi[1]
    bad = ds.with_overrides({3: {"com_m": [0.0, hi[1] + 0.1, 0.0]}, 1: {"mass_kg": ds.mass_kg[0] + 4.0}})
    out = physical_checks(bad)
    assert not out["ok"] and not out["com_in_box"][2]["ok"]
    assert out["com_in_box"][2]["outside_m"] == pytest.approx(0.1, abs=1e-12)
    assert out["total_mass"]["relative"] == pytest.approx(4.0 / ds.mass_kg.sum(), rel=1e-12)
    assert not out["total_mass"]["ok"]
    assert all(r["ok"] for i, r in enumerate(out["com_in_box"]) if i != 2)


def test_a_payload_in_link_7_is_not_a_misplaced_com():
    from wamctl.model.dynamics import Payload

    ds = P.LinkParameters.datasheet()
    m7, c7 = ds.mass_kg[6], ds.com_m[6]
    # link 7 as the identification sees it with a 1 kg payload 0.2 m out on z7: its COM far outside the link's box
    com = (m7 * c7 + 1.0 * np.array([0.0, 0.0, 0.2])) / (m7 + 1.0)
    with_payload = ds.with_overrides({7: {"mass_kg": m7 + 1.0, "com_m": com.tolist()}})
    assert not physical_checks(with_payload)["ok"]
    out = physical_checks(with_payload, payload=Payload(1.0, (0.0, 0.0, 0.2)))
    assert out["ok"] and out["com_in_box"][6]["ok"] is None
    assert out["total_mass"]["relative"] == pytest.approx(0.0, abs=1e-12)

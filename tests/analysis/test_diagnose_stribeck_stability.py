"""The Stribeck breakaway estimate of ``wamctl diagnose`` is continuous in the data (issue 31's blocker for the
compiled loop).

A joint that only sticks and slips one way leaves few sliding samples in that direction: on test_diagnose's
seed-11 Stribeck run, joint 3 has 41 positive ones, in one stall-and-slip whose speed dips to within a count's
worth of the stick threshold. One encoder count moved there (or one count flipped by the compiled loop's 1e-15
rounding, a different realisation from there on) leaves none, the fitted positive Coulomb level drops from
2.9 N m to its bound 0, and the breakaway estimate, a ratio measured against that level and multiplied back by
it, went from 3.19 to 0 N m. The breakaway levels are now measured in N m at the onsets
(:func:`wamctl.analysis.diagnosis.onsets.breakaway_reference_Nm`), and a Coulomb level no sliding sample
determines is reported as not identified.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from diagnosis_gen import generate_run

from wamctl.analysis.diagnosis.backlash import breakaway_ratio, resolution_rad
from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.analysis.diagnosis.onsets import breakaway_reference_Nm
from wamctl.analysis.diagnosis.signals import prepare_signals
from wamctl.model import params as P
from wamctl.runs.measured import load_run_data

SEED = 11
# the estimate may move by this much (relative) when the measured positions move by one encoder count; measured:
# 1.6 % on the Python loop's run (3.886 -> 3.949 N m positive, 5.458 -> 5.458 N m negative), 1.5 % on the
# compiled loop's (3.894 -> 3.951, 5.315 -> 5.315); before, 100 % (3.19 -> 0 N m)
MAX_SHIFT = 0.03


def positive_sliding(run: Path, j: int) -> int:
    """Samples of 0-based joint ``j`` the diagnosis counts as sliding in the positive direction."""
    data = load_run_data(run)
    sig = prepare_signals(data.t_s, data.col("q"), data.col("q_ref"), data.col("tau"), data.meta.sample_rate_hz)
    return int((sig.moving[:, j] & (sig.qd_rad_s[:, j] > 0)).sum())


def one_count_step(run: Path, out: Path, j: int) -> tuple[Path, int]:
    """A copy of ``run`` whose measured position of joint ``j`` is moved by one encoder count from one sample on
    (a count flipped at a stall), at the first sample where that leaves the joint no positive sliding sample;
    returns the copy and the sample (-1: no such sample near the positive sliding ones)."""
    data = load_run_data(run)
    q = data.col("q")
    sig = prepare_signals(data.t_s, q, data.col("q_ref"), data.col("tau"), data.meta.sample_rate_hz)
    pos = np.flatnonzero(sig.moving[:, j] & (sig.qd_rad_s[:, j] > 0))
    count = resolution_rad(q[:, j])
    df = pd.read_parquet(run / "data.parquet")
    col = f"q_{j + 1}"
    for k in range(pos[0] - 20, pos[-1] + 20) if len(pos) else ():
        for s in (-1.0, 1.0):
            q2 = q.copy()
            q2[k:, j] += s * count
            sig2 = prepare_signals(data.t_s, q2, data.col("q_ref"), data.col("tau"), data.meta.sample_rate_hz)
            if not (sig2.moving[:, j] & (sig2.qd_rad_s[:, j] > 0)).any():
                shutil.copytree(run, out)
                df[col] = q2[:, j]
                df.to_parquet(out / "data.parquet", index=False)
                return out, k
    return out, -1


def stribeck_entry(diag: ModelDiagnosis, j: int) -> dict:
    return next(e for e in diag.joints_[j].effects if e["name"] == "stribeck")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The seed-11 Stribeck run and its copy with one count moved, each diagnosed (no position check: the
    estimates do not use it)."""
    root = tmp_path_factory.mktemp("stribeck_stability")
    g = generate_run(root, "stribeck", SEED)
    j = g.joint - 1
    assert positive_sliding(g.path, j) > 0          # the run this test is about: a few positive sliding samples
    moved, k = one_count_step(g.path, root / "one_count", j)
    assert k >= 0, "no one-count step leaves the joint without positive sliding samples"
    diags = [ModelDiagnosis().fit(load_run_data(p)) for p in (g.path, moved)]
    return g, diags


@pytest.mark.slow
def test_breakaway_estimate_moves_little_when_one_count_moves(runs):
    g, (diag, diag_moved) = runs
    j = g.joint - 1
    rho = g.effect_spec["breakaway_ratio"]
    truth = {"pos": rho * P.TABLE_4_1_FC_POS_NM[j], "neg": rho * P.TABLE_4_1_FC_NEG_NM[j]}
    for d in (diag, diag_moved):
        assert d.effects_found_ == ["stribeck"]
    e, e_moved = stribeck_entry(diag, j), stribeck_entry(diag_moved, j)
    for key in ("pos", "neg"):
        k = f"Fs_{key}_Nm"
        a, b = e["params"][k], e_moved["params"][k]
        assert abs(b - a) <= MAX_SHIFT * a, (key, a, b)
        # the breakaway is seen a sample or two late: +9 % and +13 % here
        assert a == pytest.approx(truth[key], rel=0.2)
        for est, (lo, hi) in ((a, e["params_ci"][k]), (b, e_moved["params_ci"][k])):
            assert lo is not None and hi is not None and lo <= est <= hi
    # without positive sliding samples the positive Coulomb level is the fit's bound, not a measurement
    assert e_moved["params"]["Fc_pos_Nm"] is None and "Fc_pos_Nm" in e_moved["not_identified"]
    assert e["params"]["Fc_pos_Nm"] > 0


def test_breakaway_level_hardly_depends_on_the_reference_level():
    """The torque a joint withstood before it moved, ratio times the reference Coulomb level it was measured
    against, is about the same for references from 0.5 to 3 N m (the ratio itself is not): a slow ramp to
    3.8 N m, all of which the joint withstood."""
    dt, inertia, tol = 0.002, 0.05, 1e-4
    u = np.linspace(0.0, 3.8, 200)
    levels = []
    for ref in (0.5, 1.0, 2.0, 3.0):
        rho = breakaway_ratio(u, dt, inertia, ref, ref, 0.5, 0.5, tol)
        levels.append(rho * ref)
    assert np.ptp(levels) <= 0.02 * np.mean(levels)
    assert np.mean(levels) == pytest.approx(3.8, rel=0.03)


def test_reference_levels_floor_an_undetermined_direction():
    assert breakaway_reference_Nm(2.0, 2.5) == (2.0, 2.5)        # both determined: the model's own
    assert breakaway_reference_Nm(0.0, 2.5) == (0.5, 2.5)        # none there: a fifth of the other direction's
    # Table 4.1's most uneven joint (7) is measured against its own levels
    assert breakaway_reference_Nm(0.0538, 0.1370) == (0.0538, 0.1370)
    lo = breakaway_reference_Nm(0.0, 0.0)
    assert lo[0] > 0 and lo[1] > 0
    # continuous in the levels: a fitted level falling to zero moves its reference smoothly to the floor
    refs = [breakaway_reference_Nm(x, 2.6)[0] for x in np.linspace(0, 2.6, 27)]
    assert np.max(np.abs(np.diff(refs))) <= 0.1 + 1e-12

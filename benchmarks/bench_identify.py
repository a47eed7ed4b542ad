"""`wamctl identify` against the peers' simplest path (plain OLS on the base regressor) on simulated arms.

Each arm: links' masses, COMs and inertias scaled by factors drawn in U(0.8, 1.2), armature in U(0.9, 1.1),
Table 4.1 friction scaled by U(0.85, 1.15) (seeds 18, 19, ...); sensors as a real WAM (4096-count encoders,
2e-5 rad position noise, 0.02 N m actuation noise). Identification run: configs/excitation.yaml; held-out run:
configs/excitation_validation.yaml; both on the project's simulator.

* ours: `wamctl identify` (two-stage filtering, per-joint weights, instruments on the reference, HAC intervals,
  the physically consistent estimate).
* plain OLS: the diagnosis' filter (about 10 Hz), the same rows, ordinary least squares on the base regressor
  (what FloBaRoID's or pinocchio's simplest path gives), no weights, no constraints.

Reported per arm and method: the condition number of the base regressor the method solves (column-
equilibrated), the held-out torque RMS per joint over the noise floor (the true arm's own model through the
same processing), the share of base parameters whose 95 % interval holds the truth (OLS: its textbook
intervals), and physical consistency (OLS: whether any physically consistent arm reproduces its base
parameters: an SDP feasibility problem). Nothing is asserted (tests/analysis/test_identification.py holds the
claims).

    python benchmarks/bench_identify.py [--arms 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "analysis"))

from test_identification import perturbed_plant, run_config, true_standard  # noqa: E402

from wamctl.analysis.identification.base import base_parameters, identifiability  # noqa: E402
from wamctl.analysis.identification.consistency import PSEUDO_BASIS  # noqa: E402
from wamctl.analysis.identification.data import run_rows  # noqa: E402
from wamctl.experiments.identify import identify  # noqa: E402
from wamctl.model.dynamics import WamDynamics  # noqa: E402
from wamctl.runs.measured import load_run_data  # noqa: E402


def ols(train, held):
    """Plain OLS on the diagnosis-filtered base regressor: estimate, textbook standard errors, condition."""
    base = base_parameters()
    rr = run_rows(load_run_data(train), WamDynamics(), window_s=None)
    Y, y, _, _ = rr.stacked()
    X = base.regressor(Y)
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ beta
    s2 = e @ e / (len(y) - X.shape[1])
    se = np.sqrt(np.diag(s2 * np.linalg.pinv(X.T @ X)))
    cond = identifiability(X, base).condition_number
    return beta, se, cond


def consistent_arm_exists(beta: np.ndarray) -> bool:
    """Whether some standard parameters with every pseudo-inertia PSD, armature and friction >= 0 reproduce
    ``beta`` exactly (to 1e-6 relative)."""
    import cvxpy as cp

    from wamctl.analysis.identification.base import ARMATURE_SLICE, FRICTION_SLICE, N_STANDARD

    K = base_parameters().matrix
    pi = cp.Variable(N_STANDARD)
    cons = [pi[ARMATURE_SLICE] >= 0, pi[FRICTION_SLICE] >= 0]
    cons += [sum(pi[10 * i + k] * PSEUDO_BASIS[k] for k in range(10)) >> 0 for i in range(7)]
    scale = np.maximum(np.abs(beta), 1e-6)
    prob = cp.Problem(cp.Minimize(cp.max(cp.abs(K @ pi - beta) / scale)), cons)
    prob.solve(solver=cp.CLARABEL)
    return prob.value is not None and prob.value < 1e-6


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--arms", type=int, default=3)
    args = ap.parse_args(argv)
    base = base_parameters()
    out = Path(tempfile.mkdtemp(prefix="bench_identify_"))
    for seed in range(18, 18 + args.arms):
        plant = perturbed_plant(seed)
        train = run_config("excitation.yaml", plant, out)
        held = run_config("excitation_validation.yaml", plant, out)
        pi_true = true_standard(plant)
        truth = base.of(pi_true)
        vr = run_rows(load_run_data(held), WamDynamics(), window_s=None)
        Yv, yv, jv, _ = vr.stacked()
        Xv = base.regressor(Yv)

        def rms(beta):
            e = yv - Xv @ beta
            return np.array([np.sqrt(np.mean(e[jv == j] ** 2)) for j in range(7)])

        floor = rms(truth)
        t0 = time.perf_counter()
        est, validation, _ = identify([train], [held])
        t_ours = time.perf_counter() - t0
        lo, hi = est.intervals()
        ours = {"cond": est.identifiability_.condition_number, "rms": validation["rms"]["identified"] / floor,
                "cover": float(np.mean((truth >= lo) & (truth <= hi))),
                "consistent": bool((est.margin_ > 0).all()), "time_s": t_ours}
        t0 = time.perf_counter()
        b_ols, se_ols, cond_ols = ols(train, held)
        t_ols = time.perf_counter() - t0
        plain = {"cond": cond_ols, "rms": rms(b_ols) / floor,
                 "cover": float(np.mean(np.abs(b_ols - truth) <= 1.96 * se_ols)),
                 "consistent": consistent_arm_exists(b_ols), "time_s": t_ols}
        print(f"arm seed {seed}: noise floor (N m) {np.round(floor, 4).tolist()}")
        for name, r in (("ours", ours), ("plain OLS", plain)):
            print(f"  {name:10s} cond {r['cond']:9.4g}  held-out RMS / floor {np.round(r['rms'], 2).tolist()}  "
                  f"worst {r['rms'].max():.2f}  truth in 95 % interval {r['cover']:.0%}  "
                  f"consistent {r['consistent']}  {r['time_s']:.1f} s")


if __name__ == "__main__":
    main()

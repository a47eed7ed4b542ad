"""Coverage of `wamctl identify`'s 95 % intervals for the base parameters, and its held-out verdicts, over seeds
with a known truth (issue 27 item 3).

Arms (``--arm``):

* ``wam4``: the runs of tests/analysis/test_identification_wam4.py (a sum of sines, the torque of the arm by
  pinocchio plus per-direction friction 1.3x the declared, 0.05 N m torque and 2e-5 rad position noise; fit and
  held-out trajectories of seeds ``100 + 2 i`` and ``101 + 2 i``), the arm either the declared wam4
  (``--scale 0``: only the friction is off, which the nominal model fits too) or links 2-4 25-35 % heavier with
  their COMs 1.5 cm off (``--scale 1``). About 6 s a seed.
* ``wam7``: tests/analysis/test_identification.py's case on the project's simulator (shipped excitation and
  validation trajectories; links of seed ``18 + i`` scaled in U(0.8, 1.2), armature in U(0.9, 1.1), friction
  Table 4.1 scaled in U(0.85, 1.15); or with ``--scale 0`` the declared arm itself, datasheet links and armature
  and Table 4.1 friction, simulator seeds ``100 + i`` and ``200 + i``). About 60 s a seed.

Truth: the base parameters of the plant's standard parameters in the estimator's own base. Per path, the share
of the determined base parameters whose 95 % interval holds the truth, with its Clopper-Pearson 95 % interval
(parameters of one seed are not independent: the interval is indicative), and the RMS of the errors in standard
errors (1 when the intervals' width is right):

* ``iv``: the data-only estimate (instruments where the reference tracks, else least squares), HAC intervals;
* ``iv+consistent``: the reported estimate (physically consistent, prior at the declared arm), posterior
  intervals (``InertialIdentification.intervals()``, what `identify` prints);
* ``ls`` and ``ls+consistent``: the same with the instruments off (least squares on every joint).

And the held-out check's verdict per seed (``identify``'s pipeline). Nothing is asserted
(tests/analysis/test_identification_coverage.py holds the claims).

    python benchmarks/bench_identify_coverage.py --arm wam4 --scale 0 --seeds 20
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "analysis"))

PATHS = ("iv", "iv+consistent", "ls", "ls+consistent")


def clopper_pearson(k: int, n: int) -> tuple[float, float]:
    lo = stats.beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return float(lo), float(hi)


def wam4_seed(i: int, scale: float, out: Path):
    import test_identification_wam4 as T

    fit = T.write_run(out / f"fit{i}", scale, 100 + 2 * i)
    held = T.write_run(out / f"held{i}", scale, 101 + 2 * i)
    return fit, held, T._truth_pi(scale)


def wam7_seed(i: int, scale: float, out: Path):
    from test_identification import perturbed_plant, run_config, true_standard

    from wamctl.model import params as P
    from wamctl.model.friction import FrictionModel

    if scale:
        plant = perturbed_plant(18 + i)
        return (run_config("excitation.yaml", plant, out), run_config("excitation_validation.yaml", plant, out),
                true_standard(plant))
    # the declared arm itself (datasheet links and armature, Table 4.1 friction); the simulator's seeds vary
    plant = perturbed_plant(18 + i, share=0.0)
    arm = P.LinkParameters.datasheet().armature_kg_m2
    for j in range(P.N_JOINTS):
        plant["links"][j + 1]["armature_kg_m2"] = float(arm[j])
    plant["friction"] = {"joints": FrictionModel.table_4_1().to_dict()["joints"]}
    return (run_config("excitation.yaml", plant, out, seed=100 + i),
            run_config("excitation_validation.yaml", plant, out, seed=200 + i), true_standard(plant))


def errors(est, truth_beta: np.ndarray) -> dict:
    """Per estimate, for each determined base parameter: (estimate - truth) / standard error, and the interval's
    half-width in standard errors (:meth:`InertialIdentification.critical_values`)."""
    ok = est.identified_
    return {"": (((est.beta_wls_ - truth_beta) / est.se_)[ok], est.critical_values("wls")[ok]),
            "+consistent": (((est.beta_ - truth_beta) / est.se_post_)[ok], est.critical_values()[ok])}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--arm", choices=("wam4", "wam7"), default="wam4")
    ap.add_argument("--scale", type=float, default=1.0, help="0: the plant is the declared arm (friction aside)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--no-ls", action="store_true", help="skip the least-squares paths")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    from wamctl.analysis.identification.estimator import InertialIdentification
    from wamctl.experiments.identify import held_out_check, identify

    out = Path(tempfile.mkdtemp(prefix="bench_identify_coverage_"))
    z: dict[str, list] = {p: [] for p in PATHS}
    verdicts = []
    t0 = time.perf_counter()
    for i in range(args.first, args.first + args.seeds):
        make = wam4_seed if args.arm == "wam4" else wam7_seed
        fit, held, pi_true = make(i, args.scale, out / str(i))
        est, validation, _ = identify([fit], [held])
        truth = est.base_.of(pi_true)
        check = held_out_check(validation, sorted({j for rr in est.rows_ for j in rr.joints}))
        verdicts.append(check["verdict"])
        for k, v in errors(est, truth).items():
            z["iv" + k].append(v)
        if not args.no_ls:
            ls_rows = [replace(rr, tracking_share=np.full(rr.n_joints, np.inf)) for rr in est.rows_]
            ls = InertialIdentification(dynamics=est.dynamics_, friction=est.friction).fit(ls_rows)
            for k, v in errors(ls, truth).items():
                z["ls" + k].append(v)
        cover = {p: float(np.mean(np.abs(z[p][-1][0]) <= z[p][-1][1])) for p in PATHS if z[p]}
        print(f"seed {i}: verdict {check['verdict']}, ratios "
              f"{ {j: round(r, 4) for j, r in check['ratio'].items()} }, coverage "
              f"{ {p: round(c, 3) for p, c in cover.items()} }", flush=True)
    print(f"\n{args.arm}, scale {args.scale}, {args.seeds} seeds from {args.first}, "
          f"{time.perf_counter() - t0:.0f} s")
    for p in PATHS:
        if not z[p]:
            continue
        zz = np.concatenate([a for a, _ in z[p]])
        crit = np.concatenate([c for _, c in z[p]])
        k, n = int(np.sum(np.abs(zz) <= crit)), len(zz)
        k_n = int(np.sum(np.abs(zz) <= 1.959964))
        lo, hi = clopper_pearson(k, n)
        print(f"  {p:14s} truth inside 95 % interval {k}/{n} = {k / n:.3f} (Clopper-Pearson {lo:.3f}-{hi:.3f}; "
              f"half-width median {np.median(crit):.2f} SE, at 1.96 SE: {k_n / n:.3f}); "
              f"RMS error {np.sqrt(np.mean(zz ** 2)):.2f} SE, mean {zz.mean():+.2f}")
    print("  held-out verdicts:", {v: verdicts.count(v) for v in sorted(set(verdicts))})


if __name__ == "__main__":
    main()

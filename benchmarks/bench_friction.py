"""Benchmark: wall time of the full seven-joint friction sweep (8 speeds x 2 directions per joint) on the
simulated arm, and of the identification that follows.

    .venv/bin/python benchmarks/bench_friction.py [--joints 1 2 ...] [--speeds ...] [--keep DIR]

Prints the arm time of the sweep, the wall time of the simulation (and the real-time factor), of the whole
`friction-id` pipeline (sweep recorded, identification, report), of the identification alone (segments, map, fits
and model selection) and of the report alone, for comparison of a plain pandas CSV copy of the table, and the
worst relative error of the identified Coulomb and viscous parameters against the simulated plant (Table 4.1).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from wamctl.analysis.friction_id.identify import identify
from wamctl.backends import make_backend
from wamctl.experiments import friction_sweep as fs
from wamctl.experiments.common import closed_loop_stage, make_joint_controller
from wamctl.experiments.runner import run_spec
from wamctl.model import params as P
from wamctl.model.friction import FrictionModel
from wamctl.report.friction import friction_document
from wamctl.runs.measured import load_run_data
from wamctl.specs import parse_spec


def sweep_spec(joints, speeds) -> dict:
    return {"kind": "friction_sweep", "name": "bench-friction", "seed": 7, "backend": {"kind": "sim"},
            "plant": {"friction": "table_4_1",
                      "sensors": {"encoder_counts_per_rev": P.ENCODER_COUNTS_PER_REV, "position_noise_rad": 2e-5}},
            "controller": {"kind": "pd_g"},
            "sweep": {"joints": joints, "velocities_rad_s": speeds,
                      "travel_rad": {j: (1.5 if j == 7 else 0.6 if j == 2 else 0.8) for j in joints}}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--joints", type=int, nargs="+", default=list(range(1, 8)))
    ap.add_argument("--speeds", type=float, nargs="+", default=fs.DEFAULT_VELOCITIES_RAD_S)
    ap.add_argument("--keep", type=Path, default=None, help="keep the run directory under this folder")
    a = ap.parse_args()

    spec = parse_spec(sweep_spec(a.joints, a.speeds), "bench")
    out = a.keep or Path(tempfile.mkdtemp(prefix="bench_friction_"))
    plan = fs.plan(spec)
    arm_s = plan.duration_s
    n_moves = len(fs.build_reference(spec)[1])

    # 1. the simulation alone, in memory
    t0 = time.perf_counter()
    with make_backend(spec) as backend:
        rows = closed_loop_stage(backend, make_joint_controller(spec), plan.reference, None)
    t_sim = time.perf_counter() - t0
    # 2. the whole pipeline as `wamctl friction-id SPEC` runs it: sweep recorded to a run directory,
    #    identification, friction_model.yaml, report
    t0 = time.perf_counter()
    outcome = run_spec(spec, None, out, None, make_report=True)
    t_all = time.perf_counter() - t0
    # 3. the analysis steps again, timed on their own
    rd = load_run_data(outcome.path)
    t0 = time.perf_counter()
    ident = identify(rd)
    t_ident = time.perf_counter() - t0
    t0 = time.perf_counter()
    friction_document(rd, ident, out / "report_again", "bench")
    t_report = time.perf_counter() - t0
    t0 = time.perf_counter()
    rd.data.to_csv(out / "report_again" / "data_again.csv", index=False)  # a plain CSV copy, for comparison
    t_csv = time.perf_counter() - t0

    truth = FrictionModel.table_4_1()
    idx = [j - 1 for j in a.joints]
    err = {k: np.abs(getattr(ident.model, k)[idx] / getattr(truth, k)[idx] - 1).max() * 100
           for k in ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad", "viscous_neg_Nm_s_rad")}
    acc = int(ident.map["accepted"].sum())
    print(f"friction sweep: joints {a.joints}, {len(a.speeds)} speeds x 2 directions = {n_moves} moves")
    print(f"  arm time                          {arm_s:8.1f} s ({len(rows)} ticks at {P.CONTROL_RATE_HZ:.0f} Hz)")
    print(f"  simulation only                   {t_sim:8.2f} s wall ({arm_s / t_sim:.0f}x real time)")
    print(f"  wamctl friction-id end to end     {t_all:8.2f} s wall (sweep + recording + identification "
          f"+ report; status {outcome.status})")
    print(f"    of which identification         {t_ident:8.2f} s wall ({acc}/{len(ident.map)} segments used)")
    print(f"    of which report                 {t_report:8.2f} s wall")
    print(f"  pandas to_csv of the same table   {t_csv:8.2f} s wall (not part of the above: what a plain CSV copy "
          "would cost; the store's writer is faster)")
    print(f"  worst error vs truth (%): Fc+ {err['fc_pos_Nm']:.2f}, Fc- {err['fc_neg_Nm']:.2f}, "
          f"sigma2+ {err['viscous_pos_Nm_s_rad']:.2f}, sigma2- {err['viscous_neg_Nm_s_rad']:.2f}")
    print(f"  chosen models { {j: ji.chosen for j, ji in ident.joints.items()} }")
    print(f"  run directory {outcome.path}")


if __name__ == "__main__":
    main()

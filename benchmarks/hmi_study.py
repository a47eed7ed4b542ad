"""The virtual-subject study of thesis 6.5 on the simulated arm: subjects x the six controls x the eight spots.

Each (subject, condition) is one ``hmi_block`` run (the same spec machinery as ``wamctl hmi-session``), one attempt
per spot by default, as in the thesis' study with nine subjects (Table 6.10). The six conditions are the thesis'
experiments E1-E6 (6.5.1): the four-directional control (MA 300 ms) and the vector control (Kalman, Q = 0.001), each
with the single, dual and cubic velocity profiles. The virtual subjects differ in seed and skill. At the end the
runs are summarised into one :class:`~wamctl.analysis.hmi_results.HmiResults` (:func:`wamctl.report.hmi.
results_from_runs`): hit rates and execution times per location and per subject, the ANOVA, and the study report
(``<out>/study/report.md``). It also prints the simulation speed (arm time over wall time).

Usage::

    .venv/bin/python benchmarks/hmi_study.py [--subjects 3] [--attempts 1] [--jobs 2] [--out runs/hmi_study]
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pandas as pd

#: The thesis' experiments of 6.5.1, in its order.
CONDITIONS = {
    "E1": {"strategy": "four", "filter": {"kind": "ma", "window_s": 0.3}, "profile": {"kind": "single"}},
    "E2": {"strategy": "four", "filter": {"kind": "ma", "window_s": 0.3}, "profile": {"kind": "dual"}},
    "E3": {"strategy": "four", "filter": {"kind": "ma", "window_s": 0.3}, "profile": {"kind": "cubic"}},
    "E4": {"strategy": "vector", "filter": {"kind": "kalman", "q": 0.001}, "profile": {"kind": "single"}},
    "E5": {"strategy": "vector", "filter": {"kind": "kalman", "q": 0.001}, "profile": {"kind": "dual"}},
    "E6": {"strategy": "vector", "filter": {"kind": "kalman", "q": 0.001}, "profile": {"kind": "cubic"}},
}
#: Virtual subjects: id, seed, skill (from expert to fairly naive).
SUBJECTS = [("S1", 11, 0.9), ("S2", 22, 0.6), ("S3", 33, 0.3), ("S4", 44, 0.8), ("S5", 55, 0.5), ("S6", 66, 0.4),
            ("S7", 77, 0.75), ("S8", 88, 0.55), ("S9", 99, 0.2)]


def block_spec(subject: tuple[str, int, float], condition: str, attempts: int, seed: int) -> dict:
    sid, sseed, skill = subject
    return {"kind": "hmi_block", "name": f"{sid}-{condition}", "seed": seed,
            "hmi": {"subject": {"id": sid, "seed": sseed, "skill": skill}, "condition": condition,
                    "attempts": attempts, **CONDITIONS[condition]}}


def run_one(args: tuple[dict, str]) -> tuple[str, float, float]:
    """Run one block; returns (run directory, arm time, wall time)."""
    spec_dict, out = args
    from wamctl.experiments.runner import run_spec
    from wamctl.specs import parse_spec
    spec = parse_spec(spec_dict)
    t0 = time.perf_counter()
    outcome = run_spec(spec, None, out, None, make_report=False)
    wall = time.perf_counter() - t0
    trials = pd.read_csv(outcome.path / "trials.csv")
    ev = pd.read_csv(outcome.path / "hmi_events.csv")
    arm_time = float(ev["t_s"].max()) if len(ev) else 0.0
    print(f"{spec.name:10s} {outcome.status:9s} hits {int(trials['hit'].sum())}/{len(trials)}  "
          f"mean time {trials['time_s'].mean():5.1f} s  arm {arm_time:6.1f} s in {wall:5.1f} s wall "
          f"({arm_time / wall:4.1f}x)", flush=True)
    return str(outcome.path), arm_time, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=3, help=f"number of virtual subjects (1-{len(SUBJECTS)})")
    ap.add_argument("--attempts", type=int, default=1, help="attempts per spot")
    ap.add_argument("--conditions", default=",".join(CONDITIONS), help="comma-separated, from E1..E6")
    ap.add_argument("--jobs", type=int, default=1, help="blocks run in parallel processes")
    ap.add_argument("--out", type=Path, default=Path("runs/hmi_study"))
    ap.add_argument("--seed", type=int, default=1, help="seed of the simulated arm")
    args = ap.parse_args()
    conditions = [c.strip() for c in args.conditions.split(",") if c.strip()]
    jobs = [(block_spec(s, c, args.attempts, args.seed), str(args.out / "runs"))
            for s in SUBJECTS[: args.subjects] for c in conditions]
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            done = list(pool.map(run_one, jobs))
    else:
        done = [run_one(j) for j in jobs]
    wall = time.perf_counter() - t0
    arm = sum(d[1] for d in done)
    n_trials = len(jobs) * 8 * args.attempts

    from wamctl.report.hmi import results_from_runs, study_report, trials_from_runs
    run_dirs = [Path(d[0]) for d in done]
    trials = trials_from_runs(run_dirs)
    by_location = results_from_runs(run_dirs, unit="location")
    by_subject = results_from_runs(run_dirs, unit="subject")
    pd.set_option("display.width", 200)
    print(f"\n{len(run_dirs)} blocks, {len(trials)} trials; {arm:.0f} s of arm time in {wall:.0f} s wall "
          f"({arm / max(wall, 1e-9):.1f}x real time with {args.jobs} job(s)); "
          f"{arm / max(n_trials, 1):.1f} s of arm time per trial on average")
    print("\nConditions: " + "; ".join(f"{k} = {v['strategy']}/{v['filter']['kind']}/{v['profile']['kind']}"
                                       for k, v in CONDITIONS.items() if k in conditions))
    print("\nHits (%) per location (Tables 6.2-6.4 layout):")
    print(by_location.table("hit_pct").round(1).to_string())
    print("\nMean execution time (s) per location:")
    print(by_location.table("mean_time_s").round(2).to_string())
    print("\nHits (%) per subject (Table 6.10 layout):")
    print(by_subject.table("hit_pct").round(1).to_string())
    print("\nMean execution time (s) per subject:")
    print(by_subject.table("mean_time_s").round(2).to_string())
    outcome = trials.groupby("condition")["outcome"].value_counts().unstack(fill_value=0)
    print("\nOutcomes per condition:")
    print(outcome.to_string())
    doc = study_report(run_dirs, args.out / "study")
    written = doc.write(args.out / "study", "report")
    try:
        analysis = (by_subject if by_subject.data["subject"].nunique() > 1 else by_location).analyse()
        for m, a in analysis.one_way.items():
            print(f"\nOne-way ANOVA of {m}:")
            print(a.to_pandas().round(4).to_string())
    except Exception as exc:  # noqa: BLE001 - the tables above are the point
        print(f"\nno ANOVA: {exc}")
    (args.out / "study").mkdir(parents=True, exist_ok=True)
    (args.out / "study" / "timing.json").write_text(json.dumps(
        {"blocks": len(run_dirs), "trials": len(trials), "arm_time_s": arm, "wall_s": wall, "jobs": args.jobs}))
    print("\nwrote " + ", ".join(str(p) for p in written))


if __name__ == "__main__":
    main()

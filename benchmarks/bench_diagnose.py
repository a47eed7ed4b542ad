"""Acceptance study and speed of ``wamctl diagnose`` (issue 5).

(a) Study: generated measured runs (tests/analysis/diagnosis_gen.py: the real simulator, one undeclared effect at a
    random joint with a random magnitude, or none), ``runs-per-effect`` per effect of the six plus ``clean``
    clean runs, each diagnosed; prints the confusion table (true effect x first named effect) and the rates
    of the acceptance criteria, and writes them to docs/diagnosis-validation.md.
(b) Speed: one long run (``--long-samples``, a few hundred thousand samples) diagnosed, timed.

Usage::

    .venv/bin/python benchmarks/bench_diagnose.py                 # 10 per effect + 20 clean, and the timing
    .venv/bin/python benchmarks/bench_diagnose.py --runs-per-effect 2 --clean 4 --no-timing
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "analysis"))

from diagnosis_gen import EFFECTS, generate_run  # noqa: E402

SEED_BASE = 50_000          # study seeds: SEED_BASE + 1000 * effect index + run index (never used by the tests)


def criteria(result: dict, effect: str | None, joint: int | None) -> dict:
    """The acceptance criteria of one diagnosed run.

    Torque and position ratios: after / before on held-out data; at the effect's joint for joint effects,
    and pooled over the diagnosed joints (root of the summed squares) for payload and delay."""
    found = result.get("effects_found") or []
    joints = result.get("joints") or {}
    out = {"effect": effect or "none", "joint": joint, "found": ",".join(found) or "-",
           "first": found[0] if found else "none", "conclusive": bool(result.get("conclusive", True))}
    if effect is None:
        out["correct"] = not found
        return out
    out["correct"] = bool(found) and found[0] == effect
    out["only"] = found == [effect]

    def ratio(key, unit):
        kb, ka = f"{key}_before_{unit}", f"{key}_after_{unit}"
        if joint is not None:
            d = joints.get(str(joint))
            if not d or d[kb] is None or d[ka] is None or d[kb] <= 0:
                return np.nan
            return d[ka] / d[kb]
        pairs = [(d[kb], d[ka]) for d in joints.values() if d[kb] is not None and d[ka] is not None]
        if not pairs:
            return np.nan
        b, a = np.array(pairs).T
        return float(np.sqrt(np.sum(a ** 2) / np.sum(b ** 2))) if np.sum(b) > 0 else np.nan

    out["torque_ratio"] = ratio("torque_rms", "Nm")
    out["position_ratio"] = ratio("position_rms", "rad")
    return out


def one_run(args) -> dict:
    effect, seed, root = args
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.experiments.diagnose import simulate_positions
    from wamctl.runs.measured import load_run_data

    t0 = time.perf_counter()
    g = generate_run(root, effect, seed)
    t1 = time.perf_counter()
    diag = ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(g.path))
    t2 = time.perf_counter()
    out = criteria(diag.to_dict(str(g.path)), effect, g.joint)
    out.update(seed=seed, spec=str(g.effect_spec), samples=g.n_samples, sim_s=t1 - t0, diagnose_s=t2 - t1)
    return out


def study(runs_per_effect: int, clean: int, workers: int) -> pd.DataFrame:
    jobs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, effect in enumerate(EFFECTS):
            jobs += [(effect, SEED_BASE + 1000 * k + i, tmp) for i in range(runs_per_effect)]
        jobs += [(None, SEED_BASE + 9000 + i, tmp) for i in range(clean)]
        rows = []
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for i, r in enumerate(pool.map(one_run, jobs)):
                rows.append(r)
                print(f"[{i + 1}/{len(jobs)}] {r['effect']:<16} joint {r['joint']}  found {r['found']:<28} "
                      f"torque {r.get('torque_ratio', np.nan):.3f}  position {r.get('position_ratio', np.nan):.3f}"
                      f"  ({r['diagnose_s']:.1f} s)", flush=True)
    return pd.DataFrame(rows)


def summarise(df: pd.DataFrame) -> tuple[pd.DataFrame, dict]:
    names = list(EFFECTS) + ["none"]
    conf = pd.crosstab(pd.Categorical(df["effect"], names), pd.Categorical(df["first"], names),
                       rownames=["true effect"], colnames=["first named"], dropna=False)
    eff = df[df["effect"] != "none"]
    cln = df[df["effect"] == "none"]
    rates = {
        "effect runs": len(eff),
        "clean runs": len(cln),
        "injected effect named first": float(eff["correct"].mean()) if len(eff) else np.nan,
        "injected effect the only one named": float(eff["only"].mean()) if len(eff) else np.nan,
        "clean runs reporting nothing": float(cln["correct"].mean()) if len(cln) else np.nan,
        "torque RMS after <= 1/3 before": float((eff["torque_ratio"] <= 1 / 3).mean()) if len(eff) else np.nan,
        "position RMS dropped": float((eff["position_ratio"] < 1).mean()) if len(eff) else np.nan,
        "median diagnose time (s)": float(df["diagnose_s"].median()),
    }
    return conf, rates


def per_effect(df: pd.DataFrame) -> pd.DataFrame:
    eff = df[df["effect"] != "none"]
    return eff.groupby("effect").agg(runs=("correct", "size"), named_first=("correct", "mean"),
                                     only=("only", "mean"),
                                     torque_le_third=("torque_ratio", lambda x: float((x <= 1 / 3).mean())),
                                     median_torque_ratio=("torque_ratio", "median"),
                                     position_dropped=("position_ratio", lambda x: float((x < 1).mean())),
                                     median_position_ratio=("position_ratio", "median"))


def timing(n_samples: int) -> dict:
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.experiments.diagnose import simulate_positions
    from wamctl.runs.measured import load_run_data

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        g = generate_run(tmp, "position_ripple", SEED_BASE + 99_000, duration_s=n_samples / 500.0)
        t1 = time.perf_counter()
        data = load_run_data(g.path)
        t2 = time.perf_counter()
        diag = ModelDiagnosis(simulator=simulate_positions).fit(data)
        t3 = time.perf_counter()
        diag_nosim = ModelDiagnosis().fit(data)
        t4 = time.perf_counter()
    return {"samples": len(data.data), "simulate_s": t1 - t0, "load_s": t2 - t1, "diagnose_s": t3 - t2,
            "diagnose_without_position_check_s": t4 - t3, "effects_found": diag.effects_found_,
            "same_without_check": diag_nosim.effects_found_ == diag.effects_found_}


def markdown(conf: pd.DataFrame, rates: dict, per: pd.DataFrame, df: pd.DataFrame, speed: dict | None) -> str:
    from wamctl.report.document import markdown_table

    lines = ["# Diagnosis validation (`wamctl diagnose`, issue 5)", "",
             "Written by `benchmarks/bench_diagnose.py`. Measured runs are generated by "
             "`tests/analysis/diagnosis_gen.py`: "
             "the real simulator (Table 4.1 friction, 4096-count encoders, libbarrett PD + gravity gains) along a "
             "varied excitation of LSPB moves, with one undeclared effect at a random joint, magnitude and seed "
             "(ranges in the generator's docstring), or none. Each run is diagnosed with the default settings "
             "(alpha = 0.01 per run, Bonferroni over joints x tests, minimum effect 5 % of the residual "
             "variance, each joint's sliding samples cut into 10 contiguous blocks dealt into 5 folds).", "",
             "## Confusion table (true effect x first effect named)", "",
             markdown_table(conf.rename_axis(index="true \\ named")), "",
             "## Acceptance rates", ""]
    for k, v in rates.items():
        lines.append(f"- {k}: {v:.3f}" if isinstance(v, float) else f"- {k}: {v}")
    lines += ["", "Torque and position ratios are after / before on held-out data, at the effect's joint "
              "(pooled over joints for payload and delay).", "", "## Per effect", "",
              markdown_table(per, 3), ""]
    if speed:
        lines += ["## Speed", "",
                  f"`diagnose` on {speed['samples']} samples ({speed['samples'] / 500:.0f} s at 500 Hz): "
                  f"{speed['diagnose_s']:.1f} s including the closed-loop position check (which simulates at "
                  f"most 60000 samples, one half scored), "
                  f"{speed['diagnose_without_position_check_s']:.1f} s without it "
                  f"(on a shared 2-core machine).", ""]
    lines += ["## Known limits", "",
              "- Delay: on this arm a delay longer than about 10 ms destabilises libbarrett's gains, so the "
              "generator draws 2-8 ms. The model with the delay found leaves the same residual as a model file "
              "declaring the true delay (tests/analysis/test_diagnose.py), i.e. the noise floor of the residual "
              "(encoder "
              "quantisation through the second derivative); a 3-5 ms delay is only two or three times that "
              "floor, so its held-out torque RMS can drop by less than a factor three although the delay is "
              "named and estimated within about 0.5 ms. Delays of one sample period or less are not named (they "
              "cannot be told from the logging convention).",
              "- Stribeck on a joint that sticks and slips: found at the breakaways, but a closed-loop "
              "re-simulation of stick-slip is chaotic, so its position RMS does not always drop; a joint that "
              "sticks again within about 80 ms every time it moves leaves no sliding samples and is skipped.",
              "- Backlash needs at least three reversals of the joint in the run; payload and delay are named "
              "only when most joints show them alike.",
              ""]
    lines += ["## Every run", "", markdown_table(df.drop(columns=["spec"]).round(4), 4), ""]
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs-per-effect", type=int, default=10)
    ap.add_argument("--clean", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--long-samples", type=int, default=300_000)
    ap.add_argument("--no-timing", action="store_true")
    ap.add_argument("--no-study", action="store_true")
    ap.add_argument("--write", type=Path, default=ROOT / "docs" / "diagnosis-validation.md",
                    help="Markdown file for the results ('-' to skip)")
    a = ap.parse_args(argv)
    df = conf = rates = per = None
    if not a.no_study:
        df = study(a.runs_per_effect, a.clean, a.workers)
        conf, rates = summarise(df)
        per = per_effect(df)
        print("\nconfusion table (rows: true effect, columns: first effect named)")
        print(conf.to_string())
        print()
        for k, v in rates.items():
            print(f"{k}: {v:.3f}" if isinstance(v, float) else f"{k}: {v}")
        print()
        print(per.to_string())
    speed = None
    if not a.no_timing:
        speed = timing(a.long_samples)
        print(f"\ndiagnose on {speed['samples']} samples: {speed['diagnose_s']:.1f} s "
              f"({speed['diagnose_without_position_check_s']:.1f} s without the position check); "
              f"simulating the data took {speed['simulate_s']:.1f} s; found {speed['effects_found']}")
    if df is not None and str(a.write) != "-":
        a.write.parent.mkdir(parents=True, exist_ok=True)
        a.write.write_text(markdown(conf, rates, per, df, speed))
        print(f"wrote {a.write}")


if __name__ == "__main__":
    main()

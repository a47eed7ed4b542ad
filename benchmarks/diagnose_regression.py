"""Regression check of ``wamctl diagnose``: the same runs diagnosed by two versions of the code, compared.

A change meant to make the diagnosis faster (or tidier) must not change its results in substance. This script
diagnoses a fixed list of development runs (the ``dev`` split of benchmarks/bench_diagnose.py, both generators,
every effect, clean runs and false-alarm runs) with whatever ``wamctl`` is on the path, and writes each run's
``diagnosis.json`` mapping (and its CPU time) into a directory; ``compare`` then sets two such directories side
by side: effects found, ambiguous groups, per-joint torque RMS before/after (relative tolerance), the position
check's RMS, and the kept effects' main parameters. The position RMS is shown, not judged: near the encoder's
resolution the closed loop (quantisation, stick-slip) turns differences in the model's last digits into
differences of up to half of an error below one encoder count (scaling the logged torque by 1 + 1e-13 does as
much with the same code).

Usage (run the old version with its own tree first on the path)::

    PYTHONPATH=/work/main .venv/bin/python benchmarks/diagnose_regression.py run --out /tmp/reg-main
    PYTHONPATH=$PWD .venv/bin/python benchmarks/diagnose_regression.py run --out /tmp/reg-new
    .venv/bin/python benchmarks/diagnose_regression.py compare /tmp/reg-main /tmp/reg-new

``--runs-dir`` holds the generated dev runs (bench_diagnose.py ``--split dev --runs-dir DIR`` generates them);
``--runs`` overrides the list (run directory names), ``--no-position-check`` skips the closed-loop check.
Never run this on the report split: it is the held-out test of the method.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

# ~30 runs of the dev split: both generators, every effect, two-effect runs, clean and false-alarm runs
RUNS = (
    [f"sim-{e}-{50_000 + 1000 * k + i}" for k, e in enumerate(
        ("stribeck", "position_ripple", "payload", "delay", "friction_drift", "backlash")) for i in (0, 1)]
    + ["sim-clean-59000", "sim-clean-59001"]
    + [f"ind-dev-{e}-00{i}" for e in ("stribeck", "position_ripple", "payload", "delay", "friction_drift",
                                      "backlash") for i in (0, 1)]
    + ["ind-dev-pair-delay+stribeck-002", "ind-dev-pair-stribeck+payload-000",
       "ind-dev-pair-position_ripple+friction_drift-001"]
    + ["ind-dev-clean-nominal-000", "ind-dev-clean-heavier_3_4-001", "ind-dev-clean-random_10pct-002"]
    + ["fa-dev-clean-heavier_3_4-001", "fa-dev-clean-random_10pct-002"]
)
RMS_RTOL = 0.02            # torque / position RMS: relative tolerance
PARAM_RTOL = 0.02          # effect parameters: relative tolerance ...
PARAM_ATOL = 1e-6          # ... or this absolute one (parameters near zero)


def run_path(runs_dir: Path, name: str) -> Path:
    """The measured run of a dev-split job directory (the first generator keeps it under ``path.txt``)."""
    d = runs_dir / name
    return Path((d / "path.txt").read_text()) if (d / "path.txt").is_file() else d


def diagnose_one(args) -> tuple[str, dict]:
    name, runs_dir, position_check = args
    logging.disable(logging.WARNING)
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.runs.measured import load_run_data

    sim = None
    if position_check:
        from wamctl.experiments.diagnose import simulate_positions as sim
    path = run_path(Path(runs_dir), name)
    data = load_run_data(path)
    c0, t0 = time.process_time(), time.perf_counter()
    try:
        out = ModelDiagnosis(simulator=sim).fit(data).to_dict(str(path))
    except Exception as exc:  # a crash is a result to compare, not the end of the check
        out = {"error": f"{type(exc).__name__}: {exc}"}
    out["_cpu_s"], out["_wall_s"] = time.process_time() - c0, time.perf_counter() - t0
    return name, out


def cmd_run(a) -> None:
    import wamctl

    a.out.mkdir(parents=True, exist_ok=True)
    print(f"wamctl from {Path(wamctl.__file__).parent}", flush=True)
    names = a.runs.split(",") if a.runs else list(RUNS)
    jobs = [(n, str(a.runs_dir), not a.no_position_check) for n in names
            if a.force or not (a.out / f"{n}.json").is_file()]
    with ProcessPoolExecutor(max_workers=a.workers) as pool:
        for name, out in pool.map(diagnose_one, jobs):
            (a.out / f"{name}.json").write_text(json.dumps(out, default=str))
            print(f"{name:<50} {','.join(out.get('effects_found', [])) or '-':<30} "
                  f"cpu {out['_cpu_s']:.1f} s {out.get('error', '')}", flush=True)


# ---------------------------------------------------------------------------------------------- compare
def _close(a, b, rtol: float, atol: float = 0.0) -> bool:
    if a is None or b is None:
        return a is None and b is None
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(_close(x, y, rtol, atol)
                                                                         for x, y in zip(a, b))
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    a, b = float(a), float(b)
    if not (np.isfinite(a) and np.isfinite(b)):
        return (np.isnan(a) and np.isnan(b)) or a == b
    return abs(a - b) <= max(rtol * max(abs(a), abs(b)), atol)


def _params(d: dict) -> dict:
    """{(joint, effect, key): value} of the kept effects' parameters."""
    out = {}
    for j, jd in (d.get("joints") or {}).items():
        for e in jd.get("effects", []):
            for k, v in (e.get("params") or {}).items():
                if isinstance(v, (int, float, list)) or v is None:
                    out[(j, e["name"], k)] = v
    return out


def compare_one(a: dict, b: dict) -> dict:
    """The differences between two diagnoses of one run."""
    row = {"names": a.get("effects_found") == b.get("effects_found") and a.get("ambiguous") == b.get("ambiguous")
           and a.get("error") == b.get("error")}
    worst_t, worst_p, bad = 0.0, 0.0, []
    ja, jb = a.get("joints") or {}, b.get("joints") or {}
    if set(ja) != set(jb):
        bad.append(f"joints {sorted(ja)} vs {sorted(jb)}")
    for j in set(ja) & set(jb):
        for key in ("torque_rms_before_Nm", "torque_rms_after_Nm"):
            x, y = ja[j][key], jb[j][key]
            if x and y:
                worst_t = max(worst_t, abs(y / x - 1))
            elif x != y:
                bad.append(f"joint {j} {key} {x} vs {y}")
        for key in ("position_rms_before_rad", "position_rms_after_rad"):
            x, y = ja[j].get(key), jb[j].get(key)
            if x and y:
                worst_p = max(worst_p, abs(y / x - 1))
        if ja[j].get("ambiguous") != jb[j].get("ambiguous"):
            bad.append(f"joint {j} ambiguous {ja[j].get('ambiguous')} vs {jb[j].get('ambiguous')}")
    pa, pb = _params(a), _params(b)
    for k in sorted(set(pa) | set(pb), key=str):
        if not _close(pa.get(k), pb.get(k), PARAM_RTOL, PARAM_ATOL):
            bad.append(f"joint {k[0]} {k[1]}.{k[2]}: {pa.get(k)} vs {pb.get(k)}")
    row.update(torque_rms_max_rel=worst_t, position_rms_max_rel=worst_p, params_ok=not any(
        s.startswith("joint") and "." in s.split(":")[0] for s in bad), differences=bad,
        cpu_a=a.get("_cpu_s", float("nan")), cpu_b=b.get("_cpu_s", float("nan")))
    return row


def cmd_compare(a) -> int:
    names = sorted(p.stem for p in a.a.glob("*.json") if (a.b / p.name).is_file())
    ok = True
    print(f"{'run':<48} {'effects (a)':<28} {'effects (b)':<28} same  torque%  pos%  params  cpu a/b s")
    for n in names:
        da, db = (json.loads((d / f"{n}.json").read_text()) for d in (a.a, a.b))
        r = compare_one(da, db)
        good = r["names"] and r["torque_rms_max_rel"] <= RMS_RTOL and r["params_ok"]
        ok &= good
        fa = ",".join(da.get("effects_found", [])) + ("" if not da.get("ambiguous") else
                                                      " amb " + "/".join("+".join(g) for g in da["ambiguous"]))
        fb = ",".join(db.get("effects_found", [])) + ("" if not db.get("ambiguous") else
                                                      " amb " + "/".join("+".join(g) for g in db["ambiguous"]))
        print(f"{n:<48} {fa or '-':<28} {fb or '-':<28} {'yes' if r['names'] else 'NO ':<5} "
              f"{100 * r['torque_rms_max_rel']:6.2f} {100 * r['position_rms_max_rel']:6.2f}  "
              f"{'ok' if r['params_ok'] else 'DIFF':<6}  {r['cpu_a']:.1f}/{r['cpu_b']:.1f}")
        for s in r["differences"]:
            print(f"    {s}")
    ca = [json.loads((a.a / f"{n}.json").read_text()).get("_cpu_s", np.nan) for n in names]
    cb = [json.loads((a.b / f"{n}.json").read_text()).get("_cpu_s", np.nan) for n in names]
    print(f"\n{len(names)} runs; CPU per run: median {np.nanmedian(ca):.2f} s (a), {np.nanmedian(cb):.2f} s (b)")
    print("all within tolerance" if ok else "DIFFERENCES (see above)")
    return 0 if ok else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--runs-dir", type=Path, default=Path("/work/cache/runs"))
    r.add_argument("--runs", default=None, help="comma-separated run names (default: the fixed list)")
    r.add_argument("--workers", type=int, default=2)
    r.add_argument("--no-position-check", action="store_true")
    r.add_argument("--force", action="store_true", help="diagnose again runs already in --out")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "run":
        cmd_run(a)
        return 0
    return cmd_compare(a)


if __name__ == "__main__":
    sys.exit(main())

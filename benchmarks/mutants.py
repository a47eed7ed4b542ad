"""Hand-made mutation check: does the test suite notice when the core of an estimator is broken?

Each mutant below is one small, plausible bug in a module under test (a sign, an index, a constant, a dropped
term), written as an exact text replacement. For each, the script makes a scratch copy of the committed tree
(``git worktree``), applies the mutant, runs the tests that exercise that module, and records whether they went
red (the mutant is *killed*) or stayed green (it *survived*: a blind spot of the tests). Nothing in the working
tree is touched.

    .venv/bin/python benchmarks/mutants.py [--only NAME ...] [--out docs/mutation-check.md]

A mutant whose text is no longer found (the code moved) is reported as *stale*: update its replacement.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str           # module, relative to the repository
    old: str            # exact text (must occur once)
    new: str
    tests: tuple[str, ...]
    why: str            # the bug it stands for


MUTANTS: tuple[Mutant, ...] = (
    # ---------------------------------------------------------------- IFT (thesis ch. 5)
    Mutant("ift-gradient-sign", "wamctl/analysis/ift.py",
           "return psi.T @ y / len(y)",
           "return -psi.T @ y / len(y)",
           ("tests/experiments/test_ift.py",), "gradient of J with the wrong sign (eq. 2.15)"),
    Mutant("ift-hessian-scale", "wamctl/analysis/ift.py",
           "return psi.T @ psi / len(psi)",
           "return psi.T @ psi / len(psi) / 2",
           ("tests/experiments/test_ift.py",), "Gauss-Newton Hessian off by a factor (eq. 2.16)"),
    # ---------------------------------------------------------------- control law
    Mutant("pid-derivative-sign", "wamctl/control/controllers.py",
           "out[j] = kp[j] * e + state_i[j] + kd[j] * (e - e_prev) / dt + extra[j]",
           "out[j] = kp[j] * e + state_i[j] + kd[j] * (e_prev - e) / dt + extra[j]",
           ("tests/backends/test_sim.py",
            "tests/experiments/test_ift.py::test_ift_filters_invert_the_libbarrett_pid"),
           "derivative term of libbarrett's PID reversed"),
    Mutant("pid-integral-current-error", "wamctl/control/controllers.py",
           "state_i[j] += ki[j] * dt * e_prev",
           "state_i[j] += ki[j] * dt * e",
           ("tests/experiments/test_ift.py::test_ift_filters_invert_the_libbarrett_pid",),
           "integral accumulates the current error instead of the previous one (libbarrett's order)"),
    # ---------------------------------------------------------------- friction
    Mutant("stribeck-exponent", "wamctl/model/friction.py",
           "return np.exp(-(a * a))",
           "return np.exp(-a)",
           ("tests/model/test_model.py", "tests/analysis/test_friction_id.py"),
           "Stribeck decay with the wrong exponent (eq. 2.8: delta = 2 computed as 1)"),
    Mutant("classic-regressor-direction", "wamctl/model/friction.py",
           "np.multiply(qd, out[0], out=out[2])\n    np.multiply(qd, out[1], out=out[3])",
           "np.multiply(qd, out[1], out=out[2])\n    np.multiply(qd, out[0], out=out[3])",
           ("tests/analysis/test_friction_id.py",), "viscous columns of the two directions swapped"),
    # ---------------------------------------------------------------- dynamics
    Mutant("dynamics-no-armature", "wamctl/model/dynamics.py",
           "model.armature = np.array(links.armature_kg_m2)",
           "model.armature = 0.0 * np.array(links.armature_kg_m2)",
           ("tests/model/",), "reflected rotor inertia left out of the rigid-body model"),
    # ---------------------------------------------------------------- CAN wire (libbarrett's puck protocol)
    Mutant("can-position-no-sign-extension", "wamctl/backends/can/protocol/positions.py",
           "return v - (1 << POSITION_BITS) if v & (1 << (POSITION_BITS - 1)) else v",
           "return v",
           ("tests/backends/test_puck_protocol.py",), "22-bit positions read without sign extension"),
    Mutant("can-torque-slot-order", "wamctl/backends/can/protocol/torques.py",
           "bits |= (value & _TORQUE_MASK) << (TORQUE_BITS * (PUCKS_PER_TORQUE_GROUP - slot))",
           "bits |= (value & _TORQUE_MASK) << (TORQUE_BITS * (slot - 1))",
           ("tests/backends/test_puck_protocol.py",), "packed torques written in the reverse slot order"),
    Mutant("j2mp-coupling-sign", "wamctl/model/params.py",
           "    [0, -28.25, -16.8155, 0, 0, 0, 0],",
           "    [0, -28.25, 16.8155, 0, 0, 0, 0],",
           ("tests/backends/test_puck_protocol.py",), "a sign of the J2/J3 cable differential typed wrong"),
    Mutant("j2mp-transposed", "wamctl/model/transmission.py",
           'return as_joint_vectors(q_rad, "q_rad") @ np.asarray(j2mp, dtype=float).T',
           'return as_joint_vectors(q_rad, "q_rad") @ np.asarray(j2mp, dtype=float)',
           ("tests/backends/test_puck_protocol.py", "tests/model/"), "joint-to-motor map applied transposed"),
    # ---------------------------------------------------------------- gaze tracker (ASL Serial Out)
    Mutant("asl-overflow-bit-order", "wamctl/backends/gaze/asl.py",
           "out.append(b | ((overflow >> i) & 1) << 7)",
           "out.append(b | ((overflow >> (6 - i)) & 1) << 7)",
           ("tests/backends/test_gaze_formats.py",), "overflow byte's bits read in the reverse order"),
    Mutant("asl-overflow-both-sides", "wamctl/backends/gaze/asl.py",
           "overflow |= (b >> 7) << i",
           "overflow |= (b >> 7) << (6 - i)",
           ("tests/backends/test_gaze_formats.py",),
           "our encoder's overflow bits reversed (a decoder reversed the same way would agree with it)"),
    # ---------------------------------------------------------------- diagnosis (the held-out nested F-test)
    Mutant("diagnosis-no-autocorrelation", "wamctl/analysis/diagnosis/stats.py",
           "tau = 1.0 if independent else effective_tau(e1, None if groups is None else np.asarray(groups)[ok])",
           "tau = 1.0",
           ("tests/analysis/test_diagnosis_stats.py", "tests/analysis/test_diagnose.py"),
           "held-out samples counted as independent although the residual is autocorrelated"),
    Mutant("diagnosis-no-minimum-effect", "wamctl/analysis/diagnosis/stats.py",
           "lam = n_eff * min_effect / (1.0 - min_effect)",
           "lam = 0.0 * min_effect",
           ("tests/analysis/test_diagnose.py", "tests/analysis/test_diagnose_v2.py"),
           "the minimum effect size dropped from the test (any significant sliver named)"),
    # ---------------------------------------------------------------- diagnosis, second round (issue 15)
    Mutant("diagnosis-delay-sign", "wamctl/analysis/diagnosis/signals.py",
           "        return np.interp(t_s - delay_s, t_s, Y)\n    return interp_columns(t_s - delay_s, t_s, Y)",
           "        return np.interp(t_s + delay_s, t_s, Y)\n    return interp_columns(t_s + delay_s, t_s, Y)",
           ("tests/analysis/test_diagnose_v2.py", "tests/analysis/test_diagnose.py"),
           "a measurement delay applied as a lead (the delayed signal read ahead)"),
    Mutant("diagnosis-payload-without-link-prior", "wamctl/analysis/diagnosis/links.py",
           "lim = np.full(nl, scale)",
           "lim = np.full(nl, 1e-3 * scale)",
           ("tests/analysis/test_diagnose_payload.py",),
           "the links' declared accuracy left out of the payload-or-links test (any link error a payload)"),
    Mutant("diagnosis-backlash-lead-as-lag", "wamctl/analysis/diagnosis/backlash.py",
           "return float(-(sign * (q[k] - q_turn) - tol))",
           "return float(sign * (q[k] - q_turn) - tol)",
           ("tests/analysis/test_backlash_motor_side.py",),
           "a measurement that leads the link (gap on the motor side) counted as one that lags"),
    Mutant("diagnosis-ripple-harmonics-fundamental", "wamctl/analysis/diagnosis/candidates.py",
           "        z = z * z1\n    return out",
           "        z = z1\n    return out",
           ("tests/analysis/test_diagnose_ripple.py",),
           "every harmonic of a ripple given the fundamental's columns"),
    Mutant("diagnosis-rediagnose-forgets-rejections", "wamctl/analysis/diagnosis/estimator.py",
           "self._diagnose_joint(self.jd_[j], tests, dict(self.rejected_[j]))",
           "self._diagnose_joint(self.jd_[j], tests, {name: why})",
           ("tests/analysis/test_diagnose_v2.py",),
           "a joint diagnosed again forgets candidates earlier arm-wide checks ruled out"),
    # ---------------------------------------------------------------- ANOVA (thesis ch. 6)
    Mutant("anova-df-within", "wamctl/analysis/anova/oneway.py",
           "df_b, df_w = k - 1, n_total - k",
           "df_b, df_w = k - 1, n_total - k - 1",
           ("tests/analysis/test_anova.py", "tests/analysis/test_hmi_results.py"),
           "error degrees of freedom of the one-way ANOVA table off by one"),
    Mutant("greenhouse-geisser-effect-df", "wamctl/analysis/anova/repeated.py",
           "df = (eps * df_effect, eps * df_error)",
           "df = (df_effect, eps * df_error)",
           ("tests/analysis/test_anova.py", "tests/analysis/test_hmi_results.py"),
           "sphericity correction applied to the error df only"),
)


def run(cmd: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def check(m: Mutant, tree: Path, timeout_s: float) -> tuple[str, float, str]:
    """(verdict, seconds, detail) of one mutant in the scratch tree (restored afterwards)."""
    path = tree / m.path
    src = path.read_text()
    if src.count(m.old) != 1:
        return "stale", 0.0, f"text found {src.count(m.old)} times"
    path.write_text(src.replace(m.old, m.new))
    t0 = time.perf_counter()
    try:
        r = run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *m.tests], tree, timeout_s)
        verdict = "survived" if r.returncode == 0 else "killed"
        tail = (r.stdout.strip().splitlines() or [""])[-1]
    except subprocess.TimeoutExpired:
        verdict, tail = "killed", "timed out"
    finally:
        path.write_text(src)
    return verdict, time.perf_counter() - t0, tail


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="names of mutants to run (default: all)")
    ap.add_argument("--out", type=Path, help="write the table as Markdown here")
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per mutant's tests")
    args = ap.parse_args()
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    rows = []
    with tempfile.TemporaryDirectory(prefix="wamctl-mutants-") as tmp:
        tree = Path(tmp) / "tree"
        run(["git", "worktree", "add", "--detach", str(tree), "HEAD"], ROOT, 120).check_returncode()
        try:
            for m in chosen:
                verdict, secs, detail = check(m, tree, args.timeout)
                rows.append((m, verdict, secs, detail))
                print(f"{verdict:9s} {m.name:32s} {secs:6.1f} s  {detail}", flush=True)
        finally:
            run(["git", "worktree", "remove", "--force", str(tree)], ROOT, 120)
    killed = sum(v == "killed" for _, v, _, _ in rows)
    print(f"\n{killed}/{len(rows)} mutants killed")
    if args.out:
        lines = ["# Mutation check", "", "Written by `benchmarks/mutants.py`: each row is one deliberate bug in a "
                 "module under test and whether the tests named went red.", "",
                 "| mutant | module | bug | tests | verdict |", "|---|---|---|---|---|"]
        lines += [f"| `{m.name}` | `{m.path}` | {m.why} | {', '.join(f'`{t}`' for t in m.tests)} | {v} |"
                  for m, v, _, _ in rows]
        lines += ["", f"{killed} of {len(rows)} mutants killed."]
        args.out.write_text("\n".join(lines) + "\n")
    return 0 if killed == len(rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())

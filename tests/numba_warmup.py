"""The numba kernels the suite uses, compiled once before the pytest-xdist workers start (tests/conftest.py).

Each worker keeps a numba cache of its own (two processes compiling into one cache can corrupt it: see
tests/conftest.py), so in a fresh clone every worker compiled the same kernels, about 20 s of CPU each. The
controller runs this script once, in a process of its own, into a seed cache; each worker starts from a copy of
it and compiles only what the seed lacks. What is run here is small: one short run of each kind of simulation
the tests make (the fused closed loop of ``wamctl run``, the diagnosis' generated runs with an effect, the
independent generator's 4 kHz physics, the gaze tracker's inverse kinematics) and the diagnosis' stall kernels.

    NUMBA_CACHE_DIR=DIR python tests/numba_warmup.py WORKDIR
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(work: Path) -> int:
    """Each kind of kernel in a section of its own: a section that fails (a kernel renamed) is said on stderr and
    the others still compile. Exit 1 when none did."""
    sys.path[:0] = [str(HERE), str(HERE / "analysis")]
    logging.disable(logging.WARNING)
    work.mkdir(parents=True, exist_ok=True)
    failed = [name for name, section in SECTIONS if not _section(name, section, work)]
    return 1 if len(failed) == len(SECTIONS) else 0


def _section(name, section, work: Path) -> bool:
    try:
        section(work)
    except Exception as e:  # noqa: BLE001 - a warm-up: what it leaves out the workers compile
        print(f"numba_warmup: {name}: {type(e).__name__}: {e}", file=sys.stderr)
        return False
    return True


def fused_run(work: Path) -> None:
    """The fused closed loop (wamctl run) with quantised encoders, noise and each joint effect."""
    from cli_runs import ROTATION

    from wamctl.experiments.runner import run_spec
    from wamctl.specs import parse_spec
    plant = {"friction": "table_4_1", "sensors": {"position_noise_rad": 2.0e-5},
             "effects": {"stribeck": {"joints": [1, 4, 7], "breakaway_ratio": 1.5},
                         "position_ripple": {"joints": [7], "amplitude_Nm": 0.1, "period_rad": 0.2}}}
    rot = {"joints": [1, 4, 7], "mode": "all_together", "hold_s": 0.05, "settle_s": 0.0}
    for k, p in enumerate(({"friction": "table_4_1", "sensors": {"position_noise_rad": 2.0e-5}}, plant)):
        run_spec(parse_spec(dict(ROTATION, name=f"warm{k}", plant=p, rotation=rot), "warmup"), None, work / "runs",
                 None, make_report=False)


def generated_runs(work: Path) -> None:
    """The diagnosis' generated runs (tests/analysis/diagnosis_gen.py): the simulator with an effect."""
    import numpy as np
    from diagnosis_gen import make_reference, simulate

    from wamctl.model import params as P
    q0 = np.array([0.0, 0.0, 0.0, 1.9, 0.0, 0.0, 0.0])
    ref = make_reference(np.random.default_rng(0), q0, duration_s=1.0)
    enc = {"encoder_counts_per_rev": P.ENCODER_COUNTS_PER_REV}
    for plant in ({"friction": "table_4_1", "sensors": enc},
                  {"friction": "table_4_1", "sensors": {**enc, "position_noise_rad": 2e-5},
                   "effects": {"position_ripple": {"joints": [3], "amplitude_Nm": 0.3, "period_rad": 0.2}}}):
        simulate(plant, ref, q0, 1)


def kernels(work: Path) -> None:
    """Kernels the analyses and the measured-run readers call on arrays, with the array kinds they pass
    (read-only arrays are another signature to numba)."""
    import numpy as np

    from wamctl.analysis.diagnosis.backlash import breakaway_ratio, hidden_travel
    from wamctl.model import effects as E
    from wamctl.model import friction as F
    from wamctl.model import transmission as T

    def ro(a):
        a = np.array(a, float)
        a.setflags(write=False)
        return a
    u = np.concatenate([np.linspace(0.0, 1.6, 200), np.full(5, 1.6)])
    hidden_travel(u, 0.002, 0.01, 1.0, 1.0, 0.1, 0.1)
    breakaway_ratio(u, 0.002, 0.01, 1.0, 1.0, 0.1, 0.1, tol=1e-4)
    v = np.linspace(-1.0, 1.0, 8)
    F.stribeck_decay(v, 0.05, 2.0)
    F.stribeck_decay(ro(v), 0.05, 2.0)
    one, amp, ph = np.linspace(0.0, 1.0, 8), np.array([0.1]), np.array([0.0])
    two = np.linspace(0.0, 1.0, 16).reshape(8, 2)
    E.ripple_torque_Nm(two[:, 0], two[:, 1], 3.0, two[:, 1])                # strided ('A') arrays
    E.ripple_torque_Nm(two[:, 0], amp, 3.0, ph)
    E.ripple_torque_Nm(one, amp, 3.0, ph)
    E.ripple_torque_Nm(0.5, amp, 3.0, ph)
    J, c, q, out, m = np.eye(7), np.full(7, 100.0), np.zeros(7), np.empty(7), np.empty(7)
    for jj, cc in ((J, ro(c)), (ro(J), c)):
        T._joint_rad_to_counts_row(q, jj, cc, out)
        T._counts_to_joint_rad_row(q, jj, cc, out, m)
    Q, C = np.zeros((3, 7)), np.full((3, 7), 100.0)
    for jj, cc in ((J, ro(C)), (ro(J), C)):
        T._joint_rad_to_counts_rows(Q, jj, cc)
        T._counts_to_joint_rad_rows(Q, jj, cc)
    T._round_to_counts_flat(np.zeros(7), c)
    T._counts_to_rad_flat(np.zeros(7), c)


def hand_kinematics(work: Path) -> None:
    """The gaze tracker's inverse kinematics (HMI blocks)."""
    from wamctl.hmi.kinematics import HandKinematics, palm_down_rotation

    HandKinematics().solve([0.45, 0.1, 0.2], palm_down_rotation(0.0), max_iter=5)


def independent_physics(work: Path) -> None:
    """The independent generator's 4 kHz physics (tests/analysis/gen_independent): one clean run."""
    from gen_independent import cases, generate

    case = next(c for c in cases(1, 1, seed=7, n_pairs=0) if c["id"].startswith("clean"))
    generate(case, work / "independent")


SECTIONS = [("fused_run", fused_run), ("generated_runs", generated_runs), ("kernels", kernels),
            ("hand_kinematics", hand_kinematics), ("independent_physics", independent_physics)]


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))

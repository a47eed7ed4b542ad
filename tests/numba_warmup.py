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


def main(work: Path) -> None:
    sys.path[:0] = [str(HERE), str(HERE / "analysis")]
    logging.disable(logging.WARNING)
    import numpy as np
    from cli_runs import ROTATION

    work.mkdir(parents=True, exist_ok=True)
    # the fused closed loop (wamctl run), quantised encoders and noise
    spec = dict(ROTATION, plant={"friction": "table_4_1", "sensors": {"position_noise_rad": 2.0e-5}},
                rotation={"joints": [1, 4, 7], "mode": "all_together", "hold_s": 0.05, "settle_s": 0.0})
    from wamctl.experiments.runner import run_spec
    from wamctl.specs import parse_spec
    run_spec(parse_spec(spec, "warmup"), None, work / "runs", None, make_report=False)
    # the diagnosis' generated runs (tests/analysis/diagnosis_gen.py): the simulator with an effect
    from diagnosis_gen import make_reference, simulate

    from wamctl.model import params as P
    rng = np.random.default_rng(0)
    q0 = np.array([0.0, 0.0, 0.0, 1.9, 0.0, 0.0, 0.0])
    ref = make_reference(rng, q0, duration_s=1.0)
    for plant in ({"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": P.ENCODER_COUNTS_PER_REV}},
                  {"friction": "table_4_1", "effects": {"position_ripple": {"joints": [3], "amplitude_Nm": 0.3,
                                                                            "period_rad": 0.2}},
                   "sensors": {"encoder_counts_per_rev": P.ENCODER_COUNTS_PER_REV, "position_noise_rad": 2e-5}}):
        simulate(plant, ref, q0, 1)
    # the diagnosis' stall kernels
    from wamctl.analysis.diagnosis.backlash import breakaway_ratio, hidden_travel
    u = np.concatenate([np.linspace(0.0, 1.6, 200), np.full(5, 1.6)])
    hidden_travel(u, 0.002, 0.01, 1.0, 1.0, 0.1, 0.1)
    breakaway_ratio(u, 0.002, 0.01, 1.0, 1.0, 0.1, 0.1, tol=1e-4)
    # the independent generator's physics (tests/analysis/gen_independent), one short clean run
    from gen_independent import cases, generate
    case = next(c for c in cases(1, 1, seed=7, n_pairs=0) if c["id"].startswith("clean"))
    generate(case, work / "independent")


if __name__ == "__main__":
    main(Path(sys.argv[1]))

"""Real-time factor of the simulated WAM on the thesis task, against a bare pinocchio loop.

The seven-joint rotation (0.5 rad at 0.083 rad/s, all joints together, 0.3 s hold: 7.3 s of arm time) at
500 Hz under PD + gravity with Table 4.1 friction and encoder quantisation, with the physics sub-steps; and,
in the same process, a bare ``aba`` + ``integrate`` loop over the same number of physics steps. Best of N.

    python benchmarks/bench_sim.py [--repeat 5] [--substeps 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pinocchio as pin

from wamctl.backends.sim import SimBackend
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.experiments.engine import LoopRecorder, run_loop
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics, build_wam7_model
from wamctl.model.plant import Plant
from wamctl.specs import PlantSpec

Q0 = np.array([0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0])


def closed_loop(reference, substeps: int, fused: bool = True, plant: PlantSpec | None = None) -> float:
    """Seconds of one closed-loop run: compiled (``fused``, ``run_loop``'s default, what ``wamctl run`` does) or
    the Python path (``fused=False``)."""
    backend = SimBackend(Plant(plant or PlantSpec()), Q0, np.random.default_rng(0), substeps)
    ctl = JointController(P.KP, P.KD, np.zeros(7), 1 / P.CONTROL_RATE_HZ, gravity=WamDynamics().gravity_view)
    rec = LoopRecorder(len(reference), with_truth=True)
    t0 = time.perf_counter()
    with backend:
        run_loop(backend, ctl, reference, rec, fused=fused)
    return time.perf_counter() - t0


def bare_loop(n_steps: int, h: float) -> float:
    model = build_wam7_model()
    data = model.createData()
    q, v, tau = Q0.copy(), np.zeros(7), np.zeros(7)
    t0 = time.perf_counter()
    for _ in range(n_steps):
        a = pin.aba(model, data, q, v, tau)
        v = v + h * a
        q = pin.integrate(model, q, h * v)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--substeps", type=int, default=2)
    ap.add_argument("--runs", type=int, default=20, help="runs back to back for the throughput line")
    args = ap.parse_args()
    ref = ReferenceBuilder(Q0, 1 / P.CONTROL_RATE_HZ).move(dict.fromkeys(range(7), 0.5), 0.083).hold(0.3).build()
    arm_time = len(ref) / P.CONTROL_RATE_HZ
    n_phys = len(ref) * args.substeps
    closed_loop(ref, args.substeps)  # warm-up: numba caches, pinocchio
    closed_loop(ref, args.substeps, fused=False)
    t_sim = min(closed_loop(ref, args.substeps) for _ in range(args.repeat))
    t_py = min(closed_loop(ref, args.substeps, fused=False) for _ in range(args.repeat))
    t_bare = min(bare_loop(n_phys, 1 / P.CONTROL_RATE_HZ / args.substeps) for _ in range(args.repeat))
    # many runs of one spec back to back (a sweep's points, a batch of rotation runs), one core
    t0 = time.perf_counter()
    for _ in range(args.runs):
        closed_loop(ref, args.substeps)
    t_many = time.perf_counter() - t0
    n_py = max(1, args.runs // 5)
    t0 = time.perf_counter()
    for _ in range(n_py):
        closed_loop(ref, args.substeps, fused=False)
    t_many_py = (time.perf_counter() - t0) / n_py * args.runs
    print(f"seven-joint rotation: {arm_time:.2f} s of arm time, {len(ref)} control ticks, {n_phys} physics steps "
          f"({args.substeps} per tick)")
    print(f"wamctl closed loop, compiled   : {t_sim * 1e3:8.1f} ms   real-time factor {arm_time / t_sim:7.1f}x")
    print(f"wamctl closed loop, Python path: {t_py * 1e3:8.1f} ms   real-time factor {arm_time / t_py:7.1f}x")
    print(f"bare aba+integrate             : {t_bare * 1e3:8.1f} ms   real-time factor {arm_time / t_bare:7.1f}x")
    print(f"compiled closed loop vs bare loop: {t_sim / t_bare:.2f}x, vs the Python path {t_py / t_sim:.1f}x faster"
          "   (goals: >= 300x real time, <= 1.2x bare)")
    print(f"{args.runs} runs back to back, one core: compiled {args.runs / t_many:6.1f} runs/s "
          f"({args.runs * arm_time / t_many:7.0f} s of arm time per s), Python path {args.runs / t_many_py:6.1f} "
          f"runs/s (timed over {n_py}): {t_many_py / t_many:.1f}x the throughput per core")


if __name__ == "__main__":
    main()

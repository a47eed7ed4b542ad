"""wamctl's simulator against a peer simulator (MuJoCo) on the same task, in the same run.

The task is bench_sim's: the seven-joint rotation (0.5 rad at 0.083 rad/s, all joints together, 0.3 s hold:
7.3 s of arm time) at 500 Hz under PD + gravity with libbarrett's gains, torque held over each 2 ms period
(zero-order hold), two physics steps per period. Both simulators run inside the same engine
(:func:`wamctl.experiments.engine.run_loop`: safety checks, the same ``JointController`` with pinocchio
gravity compensation, the same recorder and the same encoder model), so only the physics differs; wamctl's
simulator runs that engine compiled whole (:mod:`wamctl.backends.sim_fused`, ``run_loop``'s default), the
MuJoCo peer (a subclass with its own physics) through its Python path, and a row gives wamctl's Python path too:

* wamctl: semi-implicit Euler on pinocchio's ABA + implicit, coupled stick/slip friction (Table 4.1, one
  level per direction);
* MuJoCo: the MJCF model generated in code from :mod:`wamctl.model.params`
  (:func:`wamctl.model.mjcf.wam_mjcf`), ``Euler`` integrator (semi-implicit Euler, the same scheme), the torque
  applied as ``qfrc_applied``; friction as MuJoCo's ``frictionloss`` (Coulomb) and ``damping`` (viscous),
  both symmetric, so the **mean of the two directions** of Table 4.1; the Coulomb constraint made as stiff as
  MuJoCo advises (``solreffriction`` time constant = 2 physics steps; MuJoCo's default 0.02 s lets the joints
  creep through their friction).

Printed: the times (best of ``--repeat``) with friction (the realistic case) and frictionless with ideal
sensors, the two bare floors (a pinocchio ``aba`` + ``integrate`` loop, bench_sim's, and a MuJoCo
``mj_step`` loop, over the same number of physics steps), and the ratios; then the agreement checks: mass
matrix, gravity torque and flange pose at random poses, and the frictionless closed-loop trajectories (same
controller, ideal sensors), whose largest joint position difference must stay below ``--tolerance``.

    python benchmarks/bench_peer.py [--repeat 5] [--substeps 2] [--tolerance 1e-6]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_sim import Q0, bare_loop, closed_loop  # noqa: E402  (the simulator's own benchmark)

from wamctl.backends.sim import SimBackend  # noqa: E402
from wamctl.control.controllers import JointController  # noqa: E402
from wamctl.control.trajectory import ReferenceBuilder  # noqa: E402
from wamctl.experiments.engine import LoopRecorder, run_loop  # noqa: E402
from wamctl.model import params as P  # noqa: E402
from wamctl.model.dynamics import WamDynamics  # noqa: E402
from wamctl.model.mjcf import full_mass_matrix, load_mujoco_model, mujoco_friction  # noqa: E402
from wamctl.model.plant import Plant  # noqa: E402
from wamctl.specs import PlantSpec, SensorSpec  # noqa: E402

TOLERANCE_RAD = 1e-6
IDEAL = PlantSpec(friction="none", sensors=SensorSpec(encoder_counts_per_rev=0))


class MujocoBackend(SimBackend):
    """The simulated arm with MuJoCo as its physics: SimBackend's protocol, safety, sensor chain and truth
    views, with :meth:`_advance_physics` replaced.

    Torque is applied as ``qfrc_applied`` and held for ``substeps`` ``mj_step`` calls per control period.
    The plant's friction (mean of both directions, no Stribeck) goes into the MJCF model; other plant
    effects are not modelled (the benchmark uses none).
    """

    name = "mujoco"

    def __init__(self, plant: Plant, q0_rad, rng: np.random.Generator, substeps: int = 2):
        super().__init__(plant, q0_rad, rng, substeps)
        h = self.h_s
        zero = not (np.any(plant.friction.fc_pos_Nm) or np.any(plant.friction.fc_neg_Nm)
                    or np.any(plant.friction.viscous_pos_Nm_s_rad) or np.any(plant.friction.viscous_neg_Nm_s_rad))
        self.model = load_mujoco_model(friction=None if zero else plant.friction, timestep_s=h,
                                       friction_timeconst_s=None if zero else 2 * h)
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = q0_rad
        mujoco.mj_forward(self.model, self.data)

    def _advance_physics(self) -> None:
        m, d = self.model, self.data
        d.qfrc_applied[:] = self._tau
        for _ in range(self.substeps):
            mujoco.mj_step(m, d)
            self.sensors.record_physics_step(d.qpos)
        self._q[:] = d.qpos      # SimBackend's truth views, updated in place
        self._qd[:] = d.qvel


def controller() -> JointController:
    return JointController(P.KP, P.KD, np.zeros(7), 1 / P.CONTROL_RATE_HZ, gravity=WamDynamics().gravity_view)


def timed_loop(make_backend, reference, fused: bool = True) -> tuple[float, np.ndarray]:
    """(seconds, recorded rows) of one closed loop; the backend is built before the clock starts."""
    backend = make_backend()
    ctl = controller()
    rec = LoopRecorder(len(reference), with_truth=True)
    t0 = time.perf_counter()
    with backend:
        run_loop(backend, ctl, reference, rec, fused=fused)
    return time.perf_counter() - t0, rec.result()


def sim_factory(spec: PlantSpec, substeps: int):
    return lambda: SimBackend(Plant(spec), Q0, np.random.default_rng(0), substeps)


def mujoco_factory(spec: PlantSpec, substeps: int):
    return lambda: MujocoBackend(Plant(spec), Q0, np.random.default_rng(0), substeps)


def bare_mujoco(n_steps: int, h: float) -> float:
    """MuJoCo's floor: ``mj_step`` with zero torque over ``n_steps`` (frictionless model)."""
    m = load_mujoco_model(timestep_s=h)
    d = mujoco.MjData(m)
    d.qpos[:] = Q0
    t0 = time.perf_counter()
    for _ in range(n_steps):
        mujoco.mj_step(m, d)
    return time.perf_counter() - t0


def model_agreement(n_poses: int = 200, seed: int = 0) -> dict:
    """Largest differences between the MJCF model and pinocchio at random poses within the joint limits:
    mass matrix (incl. armature), gravity torque, and flange (DH frame 7) position and rotation."""
    m = load_mujoco_model()
    d = mujoco.MjData(m)
    dyn = WamDynamics()
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "link7")
    rng = np.random.default_rng(seed)
    out = {"mass_matrix": 0.0, "gravity_Nm": 0.0, "flange_pos_m": 0.0, "flange_rot": 0.0,
           "mass_matrix_rel": 0.0, "gravity_rel": 0.0}
    for _ in range(n_poses):
        q = rng.uniform(P.Q_MIN_RAD, P.Q_MAX_RAD)
        d.qpos[:] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        M = full_mass_matrix(m, d)
        mp, g, pose = dyn.mass_matrix(q), dyn.gravity(q), dyn.link7_pose(q)
        out["mass_matrix"] = max(out["mass_matrix"], np.abs(M - mp).max())
        out["mass_matrix_rel"] = max(out["mass_matrix_rel"], np.abs(M - mp).max() / np.abs(mp).max())
        out["gravity_Nm"] = max(out["gravity_Nm"], np.abs(d.qfrc_bias - g).max())
        out["gravity_rel"] = max(out["gravity_rel"], np.abs(d.qfrc_bias - g).max() / max(np.abs(g).max(), 1e-9))
        out["flange_pos_m"] = max(out["flange_pos_m"], np.abs(d.site_xpos[site] - pose[:3, 3]).max())
        out["flange_rot"] = max(out["flange_rot"], np.abs(d.site_xmat[site].reshape(3, 3) - pose[:3, :3]).max())
    return out


def q_true(rows: np.ndarray) -> np.ndarray:
    return rows[:, 22:29]


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:
        n = os.cpu_count()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{cpu}, {n} cores, load average {load:.2f} at start; Python {platform.python_version()}, "
            f"MuJoCo {mujoco.__version__}, {platform.system()} {platform.release()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--substeps", type=int, default=2)
    ap.add_argument("--tolerance", type=float, default=TOLERANCE_RAD,
                    help="largest accepted frictionless joint position difference, rad")
    args = ap.parse_args()
    ref = ReferenceBuilder(Q0, 1 / P.CONTROL_RATE_HZ).move(dict.fromkeys(range(7), 0.5), 0.083).hold(0.3).build()
    arm_time = len(ref) / P.CONTROL_RATE_HZ
    n_phys = len(ref) * args.substeps
    h = 1 / P.CONTROL_RATE_HZ / args.substeps
    print(f"machine: {machine()}")
    print(f"seven-joint rotation: {arm_time:.2f} s of arm time, {len(ref)} control ticks at "
          f"{P.CONTROL_RATE_HZ:.0f} Hz, {n_phys} physics steps ({args.substeps} per tick, h = {h * 1e3:g} ms), "
          f"best of {args.repeat}")

    friction, ideal = PlantSpec(), IDEAL
    cases = {
        "wamctl sim, Table 4.1 friction, encoders": sim_factory(friction, args.substeps),
        "MuJoCo, mean friction, encoders": mujoco_factory(friction, args.substeps),
        "wamctl sim, frictionless, ideal sensors": sim_factory(ideal, args.substeps),
        "MuJoCo, frictionless, ideal sensors": mujoco_factory(ideal, args.substeps),
    }
    for make in cases.values():  # warm-up: numba caches, pinocchio, MuJoCo
        timed_loop(make, ref)
    closed_loop(ref, args.substeps)
    times, rows = {}, {}
    for _ in range(args.repeat):  # interleaved, so that a load change on the machine hits every case
        for name, make in cases.items():
            t, r = timed_loop(make, ref)
            times[name] = min(times.get(name, np.inf), t)
            rows[name] = r
        t, _ = timed_loop(cases["wamctl sim, Table 4.1 friction, encoders"], ref, fused=False)
        times["wamctl sim, friction, Python path"] = min(times.get("wamctl sim, friction, Python path", np.inf), t)
        t = closed_loop(ref, args.substeps)
        times["wamctl sim as in bench_sim"] = min(times.get("wamctl sim as in bench_sim", np.inf), t)
        times["bare pinocchio aba+integrate"] = min(times.get("bare pinocchio aba+integrate", np.inf),
                                                    bare_loop(n_phys, h))
        times["bare MuJoCo mj_step"] = min(times.get("bare MuJoCo mj_step", np.inf), bare_mujoco(n_phys, h))

    t_pin = times["bare pinocchio aba+integrate"]
    print(f"\n{'loop':44s} {'time (ms)':>10s} {'x real time':>12s} {'/ bare pin':>11s}")
    for name, t in times.items():
        print(f"{name:44s} {t * 1e3:10.1f} {arm_time / t:12.1f} {t / t_pin:11.2f}")
    r_f = times["wamctl sim, Table 4.1 friction, encoders"] / times["MuJoCo, mean friction, encoders"]
    r_0 = times["wamctl sim, frictionless, ideal sensors"] / times["MuJoCo, frictionless, ideal sensors"]
    r_b = times["bare pinocchio aba+integrate"] / times["bare MuJoCo mj_step"]
    print(f"\nwamctl / MuJoCo closed loop: {r_f:.2f}x with friction, {r_0:.2f}x frictionless; "
          f"bare floors pinocchio / MuJoCo: {r_b:.2f}x   (< 1: wamctl faster); machine load average "
          f"{os.getloadavg()[0]:.2f} at the end")

    agree = model_agreement()
    print(f"\nmodel agreement, MJCF vs pinocchio, 200 random poses: mass matrix {agree['mass_matrix']:.1e} kg m^2 "
          f"(relative {agree['mass_matrix_rel']:.1e}), gravity {agree['gravity_Nm']:.1e} N m "
          f"(relative {agree['gravity_rel']:.1e}), flange position {agree['flange_pos_m']:.1e} m, "
          f"rotation {agree['flange_rot']:.1e}")
    dq0 = np.abs(q_true(rows["wamctl sim, frictionless, ideal sensors"])
                 - q_true(rows["MuJoCo, frictionless, ideal sensors"]))
    dqf = np.abs(q_true(rows["wamctl sim, Table 4.1 friction, encoders"])
                 - q_true(rows["MuJoCo, mean friction, encoders"]))
    ok = dq0.max() < args.tolerance
    print(f"trajectory agreement, frictionless, ideal sensors: max |q_wamctl - q_mujoco| = {dq0.max():.2e} rad "
          f"(joint {int(dq0.max(axis=0).argmax()) + 1}); tolerance {args.tolerance:g} rad: "
          f"{'PASS' if ok else 'FAIL'}")
    final = lambda name: q_true(rows[name])[-1] - ref.q_rad[-1]  # noqa: E731
    print(f"with friction (not the same model: MuJoCo's symmetric soft Coulomb + damping vs wamctl's exact "
          f"stick/slip per direction): max |dq| = {dqf.max():.2e} rad; final error per joint (mrad) "
          f"wamctl {np.array2string(final('wamctl sim, Table 4.1 friction, encoders') * 1e3, precision=2)}, "
          f"MuJoCo {np.array2string(final('MuJoCo, mean friction, encoders') * 1e3, precision=2)}")
    fl, damp = mujoco_friction(Plant(friction).friction)
    print(f"MuJoCo friction used: frictionloss {np.array2string(fl, precision=3)} N m, "
          f"damping {np.array2string(damp, precision=3)} N m s/rad (means of both directions), "
          f"solreffriction time constant {2 * h * 1e3:g} ms")
    if not ok:
        sys.exit(1)


if __name__ == "__main__":
    main()

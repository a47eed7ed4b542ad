"""Iterative feedback tuning of the joint PIDs (thesis chapter 5) and the strategy comparison of section 5.4:
``kind: ift``.

The procedure (thesis section 5.2, per joint, decentralised: each joint's PID is tuned on its own move while the
other joints hold with their current gains):

1. **First experiment, on the plant** (the simulated arm of ``plant:`` with its friction and effects, the CAN arm
   of ``backend:``, or a recorded measured run): the joint moves ``amplitude_rad`` at ``velocity_rad_s`` (LSPB)
   and holds; ``y_tilde = y1 - r`` and ``J = 1/(2N) sum y_tilde^2`` (eq. 2.13) over settle + move + hold.
2. **Second experiment, on the model** (``ift.model``; default the rigid body with the declared friction model
   ``ift.identified_friction`` and ideal sensors): the closed loop driven by ``r - y1``. Two forms:

   * ``incremental`` (default): the model runs the task reference ``r`` and ``r + eps (r - y1)``; the second
     output is ``y2 = (y_model(r + eps (r - y1)) - y_model(r)) / eps``. For a linear loop this *is* the response
     to ``r - y1``; for the arm it is the response of the loop linearised along the task trajectory, which is
     what the sensitivity ``d y / d rho`` is. With Coulomb friction a direct experiment from rest (next item)
     mostly sticks and underestimates the gradient several-fold; the incremental form matches a
     finite-difference gradient of J on the model within a few per cent (tests/experiments/test_ift.py).
   * ``direct``: the thesis' literal form, the model at rest driven by ``q0 + eps (r - y1)``.

   ``y2`` filtered through ``(1/C) dC/drho`` of the discrete libbarrett PID gives ``psi = d y_tilde/d rho``,
   the gradient (eq. 2.15) and the Gauss-Newton Hessian (eq. 2.16): :mod:`wamctl.analysis.ift`.
3. **Update** ``rho+ = rho - gamma R^-1 dJ/drho`` (eq. 2.14) with R from the stage's method (``bfgs``: eq. 2.17,
   started from the Gauss-Newton estimate because ``B0 = I`` is not scale free with gains from 0.05 to 1e4;
   ``gauss_newton``: eq. 2.16), gains kept inside ``ift.bounds`` (projected step: gains held at a bound by the
   descent direction are left out of the solve).
4. **Safeguards, before a proposal touches the plant**: it is simulated on the model and rejected if unstable
   (safety fault of the simulated arm: velocity or position limit, non-finite torque), if the error diverges
   (``|e| > max_error_rad``), if a torque reaches ``torque_fraction`` of the WAM limit, or if J does not decrease
   on the model; a rejected proposal is retried with ``gamma * backtrack_factor`` (``backtracking`` times) and
   listed in the events (``ift_rejected``). The previous gains stay the fallback.
5. **Acceptance on the plant**: the proposal's first experiment gives its J; it is accepted when J decreased at
   ``stop_digits`` significant digits (the thesis compared "using 4 digits"), otherwise the previous gains are
   kept and the schedule moves to its next stage (BFGS gamma 0.5 -> Gauss-Newton 0.5 -> 0.1 in the thesis). A
   joint is done when its stages are used up or after ``max_iterations``.

Which positions J uses (``objective_signal``): ``measured`` (default) uses the encoder positions, as the arm
reports them and as the controller regulates them. The quantisation (one count is 3.7e-5 rad on joint 1 to
1.0e-4 rad on joint 7 through J2MP at 4096 counts/rev) is zero-mean and almost independent of the gains: it adds
a floor of about ``count^2 / 24`` (6e-11 to 4e-10 rad^2) to J, below the tuned J (1e-9 to 1e-7 rad^2 on the
simulated arm), so it does not change which gains are better, and filtering would also smooth away the
high-frequency oscillation that J must penalise. ``filtered`` applies a zero-phase 2nd-order Butterworth
low-pass (``filter_cutoff_hz``) to the measured positions before J and before forming ``r - y1``.

Run directory: ``iter-NNN-exp1.parquet`` (the plant experiments of iteration NNN, every data column plus
``joint``), ``iter-NNN-exp2.parquet`` (per joint: the second experiment's reference and output, ``psi``),
``iter-NNN-check.parquet`` (the model simulations of the proposals), ``iterations.parquet/.csv`` (one row per
joint and iteration: gains, J on the plant and the model, method, gamma, accepted), ``ift_state.json`` (written
after every completed iteration; ``--resume`` continues from it), ``tuned_gains.yaml``, and for the strategy
comparison ``compare-{pd_g,pd_g_ff,pid}.parquet``.

What lives here: the plan (:mod:`.planning`: the task reference, the model of the second experiment), the
experiments on the plant and on the model and the safeguard check (:mod:`.experiments`), the tuning loop
(:mod:`.tuner`), its saved state and tables (:mod:`.state`), the strategy comparison (:mod:`.comparison`), and the
runner's entry points ``plan`` / ``execute`` / ``resume`` (:mod:`.run`). The spec is :mod:`wamctl.specs.ift`; the
IFT maths :mod:`wamctl.analysis.ift`.

May import: the rest of wamctl.experiments (common, engine, runner) and every layer below (analysis, backends,
specs, runs, control, model, errors). Never report, commands or the CLI.
"""

from __future__ import annotations

from wamctl.experiments.ift.planning import plan
from wamctl.experiments.ift.run import execute, resume

__all__ = ["execute", "plan", "resume"]

"""Friction identification (thesis chapter 4.2): constant-velocity stages -> friction-velocity map -> models.

Pipeline (no I/O; the caller loads a :class:`~wamctl.runs.measured.RunData`)
----------------------------------------------------------------------
1. **Moves** of each joint (:mod:`.segments`): where its reference moves (``q_ref``, a hint: it gives the
   windows and the commanded speed), or, without a reference, where the measured position travels
   (:func:`.segments.detect_moves`).
2. **Constant-velocity stage** of each move, from the measured positions alone
   (:func:`.segments.constant_velocity_stage`): a line is fitted to the middle of the move and the stage grown
   outwards while the position stays within a band around the line whose width comes from the data's own
   noise (quantisation + noise + the real jitter of the motion). Acceleration phases, the stuck start of a
   slow move (the joint waits until the PD error exceeds the breakaway torque), oscillating transients and
   the creep after the reference stops all leave the line quadratically or exponentially and fall outside.
   Stages that are too short, or whose two halves move at different speeds, are rejected with a reason.
3. **Per stage** (:mod:`.velocity_map`): mean velocity = slope of the line (robust to quantisation), its
   spread from a Savitzky-Golay velocity; friction torque per sample = logged torque minus the declared
   rigid-body model, ``tau - inverse_dynamics(q, qd, qdd)`` (with gravity compensation on, the logged torque
   is the applied one, PD + g(q); the model's g(q) cancels it); mean, standard deviation and a 95 %
   confidence interval by batch means (the samples are autocorrelated).
4. **Models** (:mod:`.models`, scikit-learn style estimators, ``fit(map) -> self``, fitted attributes end in
   ``_``): :class:`.models.ClassicFriction` per direction (thesis eq. 4.1, Table 4.1 layout), symmetric, and
   :class:`.models.StribeckFriction` (eq. 2.8, per direction Fc, Fs, sigma2, shared vs and delta), by
   ``scipy.optimize.least_squares`` with an optional robust loss (``soft_l1``, ``huber``, ``cauchy``);
   parameter standard errors from the Jacobian, ``cov = s^2 (J^T J)^-1`` (classic: or the jackknife's over the
   stages, the larger), plus the one error every stage shares that their scatter cannot show: the instant
   within the held torque's control period whose rigid body it balances (``timing_shift_Nm``: gravity's
   change along the move times half a period, which at constant velocity is a viscous coefficient).
5. **Selection** (:mod:`.selection`): k-fold over segments (stratified by direction and speed), the
   held-out residuals scored by an information criterion, ``BIC = n ln(SSE_cv / n) + k ln n`` (or AIC,
   ``+ 2k``); the smallest wins.
6. **The result** (:mod:`.identify`): per joint the fits and the selection, and the chosen models as one
   :class:`~wamctl.model.friction.FrictionModel`.

The signal helpers (derivatives, noise floor, line fit, batch means) are in :mod:`.signals`.

Sign convention: friction is the torque the motor supplies to keep moving (positive for positive velocity),
as in :class:`wamctl.model.friction.FrictionModel`; Coulomb and breakaway levels are reported as magnitudes.
The formulas of the friction models themselves (the Stribeck shape, the classic regressor) live once, in
:mod:`wamctl.model.friction`.

May import: specs, runs (the measured-run data type), control, model, io, errors. Never backends, experiments,
report or the CLI.
"""

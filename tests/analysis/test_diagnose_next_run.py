"""Issue 28 item 2 (partial): the run that can tell a wrist payload from the arm's link errors.

A sweep of the elbow alone (joint 4) with a 1 kg payload: link errors within twice the declared accuracy,
fitted to the payload's torque on the sweep, reproduce it there (the two hypotheses' smaller separation is
below 1 noise floor: one run cannot tell). Among Fourier candidates in excite's parametrisation, scaled to
95 % of their closest limit by excite's own limit check, the T-optimal choice moves joints other than the elbow
and separates the hypotheses by more than the original run does and by more than the elbow alone can.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.discriminate import design_next_run, fitted_hypotheses, trajectory_rows
from wamctl.analysis.diagnosis.rigid import plausible_link_map
from wamctl.analysis.identification.excitation import ExcitationLimits
from wamctl.model.dynamics import WamDynamics
from wamctl.model.friction import FrictionModel
from wamctl.specs.excitation import ExcitationLimitsSpec

Q0 = np.array([0.0, 0.0, 0.0, 1.9, 0.0, 0.0, 0.0])
NOISE_NM = 0.05


def _elbow_sweep():
    t = np.arange(0.0, 12.0, 0.04)
    w = 2 * np.pi / 6
    q, qd, qdd = np.tile(Q0, (len(t), 1)), np.zeros((len(t), 7)), np.zeros((len(t), 7))
    q[:, 3] += 0.6 * np.sin(w * t)
    qd[:, 3] = 0.6 * w * np.cos(w * t)
    qdd[:, 3] = -0.6 * w * w * np.sin(w * t)
    return q, qd, qdd


def test_the_design_moves_other_joints_and_separates_more_than_the_sweep():
    """Original separation below 1e-6 noise floors (the links' fit reproduces the payload on the sweep to
    numerical precision); the chosen candidate moves joints beyond 4, its separation exceeds the elbow-only
    candidate's by at least 10x and 0.3 noise floors, and it keeps within 95 % of every limit. (Measured when
    written: 2e-14 on the sweep, 0.75 for all seven joints, 2e-14 for the elbow alone.)"""
    dyn = WamDynamics(None)
    rows = trajectory_rows(dyn, *_elbow_sweep())
    hyp = fitted_hypotheses(rows, 1.0, [0.02, 0.0, 0.05], plausible_link_map(), bound=2.0)
    spec = ExcitationLimitsSpec()
    limits = ExcitationLimits(*spec.arrays(), 1 - spec.torque_margin, spec.max_cartesian_speed_m_s)
    nr = design_next_run(dyn, FrictionModel.table_4_1(), Q0, hyp, NOISE_NM, rows, limits,
                         [[3], [1, 3, 4, 5], [0, 1, 2, 3, 4, 5, 6]], per_set=1)
    assert nr.original["separation"] < 1e-6
    elbow = {tuple(js): s for js, s in nr.scored}[(4,)]
    assert set(nr.trajectory.moving) - {3}
    assert nr.separation["separation"] >= max(10 * elbow, 0.3), nr.scored
    assert nr.limit_use.worst[2] <= 0.95 + 1e-9

"""A log whose torque is the controller's output (``torque: controller``, :data:`wamctl.runs.measured.
TORQUE_KINDS`): the arm also got the gravity compensation libbarrett adds downstream, which the log lacks.

A joint whose gravity torque under the declared arm is constant over the run (:data:`GRAVITY_CONSTANT_NM`: zero on
a vertical axis such as the WAM's joint 1, or held constant because the joints beyond it keep still) still has its
whole torque in the log, up to that constant, which the declared gravity adds back exactly. The analyses that take
such a run (``identify``, ``friction-id --data``, ``diagnose``) use those joints and refuse the others, each with
the reason :func:`constant_gravity` gives; this is the one place that decides which (issue 27).
"""

from __future__ import annotations

import numpy as np

GRAVITY_CONSTANT_NM = 1e-6      # a joint's gravity torque varying less over a run counts as constant


def constant_gravity(dynamics, q_rad: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """The declared arm's gravity torque (n, nj) at the logged positions ``q_rad`` (n, nj) (``dynamics``: a
    :class:`wamctl.model.dynamics.WamDynamics`), and ``{0-based joint: why}`` of every joint whose gravity torque
    varies by more than :data:`GRAVITY_CONSTANT_NM` over the run: its logged torque lacks a varying part the
    analysis cannot know. Adding the gravity to a joint not refused turns its torque into the whole torque."""
    g = dynamics.gravity_many(q_rad)
    span = np.ptp(g, axis=0)
    refused = {j: (f"torque controller: gravity compensation not logged and joint {j + 1}'s gravity torque varies "
                   f"by {span[j]:.3g} N m over the run (at most {GRAVITY_CONSTANT_NM:g} N m is usable)")
               for j in range(g.shape[1]) if span[j] > GRAVITY_CONSTANT_NM}
    return g, refused

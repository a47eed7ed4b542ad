"""Formulas of the effects a real arm has and a declared model may lack, each written once.

The simulated plant (:mod:`wamctl.model.plant`) applies them; the diagnosis (:mod:`wamctl.analysis.diagnosis`)
builds its candidate regressors from them. The Stribeck shape lives with the friction models
(:func:`wamctl.model.friction.stribeck_decay`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


def friction_drift_scale(t_s, fraction, time_constant_s):
    """Friction multiplier ``1 + fraction (1 - exp(-t / T))`` at time ``t_s`` (warming up: ``fraction < 0``).

    Broadcasts: ``t_s`` (n,) or scalar, ``fraction`` scalar or (7,)."""
    return 1.0 + np.asarray(fraction) * (1.0 - np.exp(-np.asarray(t_s) / time_constant_s))


@njit(cache=True)
def ripple_torque_Nm(q_rad, amplitude_Nm, wavenumber_rad, phase_rad=0.0):
    """Position ripple ``A sin(k q + phase)`` with ``k = 2 pi / period`` (cogging, cable forces), N m.

    Scalars (the physics kernel, per joint) or arrays (broadcast)."""
    return amplitude_Nm * np.sin(wavenumber_rad * q_rad + phase_rad)

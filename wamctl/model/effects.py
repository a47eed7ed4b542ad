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
def ripple_torque_Nm(q_rad, amplitudes_Nm, wavenumber_rad, phases_rad):
    """Position ripple ``sum_h A_h sin(h k q + phase_h)``, ``h = 1 .. H``, with ``k = 2 pi / period`` (cogging,
    cable and gear forces: a fundamental and its harmonics), N m.

    ``amplitudes_Nm``, ``phases_rad``: (H,) of harmonics 1 .. H (a one-sinusoid ripple: H = 1). ``q_rad`` a scalar
    (the physics kernel, per joint) or an array of one joint's angles."""
    out = 0.0 * q_rad
    for h in range(len(amplitudes_Nm)):
        if amplitudes_Nm[h] != 0.0:
            out = out + amplitudes_Nm[h] * np.sin((h + 1) * wavenumber_rad * q_rad + phases_rad[h])
    return out


def ripple_series(amplitude_Nm: float, phase_rad: float, harmonics=()) -> tuple[np.ndarray, np.ndarray]:
    """(amplitudes (H,), phases (H,)) of harmonics 1 .. H of a ripple given as a model file writes it: the
    fundamental's ``amplitude_Nm`` and ``phase_rad``, and ``harmonics``, the 2nd, 3rd, ... harmonics as mappings
    (or objects) with ``amplitude_Nm`` and ``phase_rad``."""
    def get(h, k):
        return float(h[k] if isinstance(h, dict) else getattr(h, k))
    amps = [float(amplitude_Nm)] + [get(h, "amplitude_Nm") for h in harmonics or ()]
    phases = [float(phase_rad)] + [get(h, "phase_rad") for h in harmonics or ()]
    return np.array(amps), np.array(phases)

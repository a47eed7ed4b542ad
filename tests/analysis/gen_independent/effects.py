"""Effect parameters drawn per case (ranges in the package docstring), link perturbations, the true friction."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from .arm import GEAR, LINK_COM, LINK_INERTIA, LINK_MASS, NOISE_FLOOR, T41_B_NEG, T41_B_POS, T41_FC_NEG, T41_FC_POS, N


def _u(rng, lo, hi):
    return float(rng.uniform(lo, hi))


SIZE_RANGES = {
    "stribeck": {"small": (1.5, 1.65), "medium": (1.65, 1.8), "large": (1.8, 2.0)},
    "position_ripple": {"small": (2.0, 3.0), "medium": (4.0, 7.0), "large": (8.0, 14.0)},
    "payload": {"small": (0.05, 0.15), "medium": (0.15, 0.5), "large": (0.5, 1.5)},
    "delay": {"small": (2.0, 4.0), "medium": (4.0, 7.0), "large": (7.0, 10.0)},
    "friction_drift": {"small": (0.15, 0.25), "medium": (0.25, 0.4), "large": (0.4, 0.6)},
    "backlash": {"small": (0.002, 0.004), "medium": (0.004, 0.008), "large": (0.008, 0.015)},
}


def draw_effect(name, joint, size, rng, fric, noise):
    """Concrete parameters of one effect (joint 0-based or None)."""
    lo, hi = SIZE_RANGES[name][size]
    if name == "stribeck":
        ratio = _u(rng, lo, hi)
        kind = ["exp_delta1", "exp_delta1.5", "lorentz"][int(rng.integers(3))]
        return dict(ratio=ratio, ratio_pos=ratio * _u(rng, 0.97, 1.03), ratio_neg=ratio * _u(rng, 0.97, 1.03),
                    vs_rad_s=_u(rng, 0.02, 0.05), shape=kind)
    if name == "position_ripple":
        snr = _u(rng, lo, hi)
        fc = 0.5 * (fric["Fc_pos"][joint] + fric["Fc_neg"][joint])
        amp = min(math.sqrt(2.0) * snr * NOISE_FLOOR[noise][joint], 0.8 * fc)  # RMS = snr x floor
        m = int(rng.integers(1, 5))
        period = float(np.clip(2 * np.pi / (GEAR[joint] * m), 0.02, 1.0))
        nh = int(rng.integers(2, 4))
        c = np.array([1.0, _u(rng, 0.2, 0.6), _u(rng, 0.1, 0.4) if nh == 3 else 0.0])
        c = c / np.linalg.norm(c)
        return dict(amplitude_Nm=float(amp), snr_target=snr, period_rad=period, motor_rev_harmonic=m,
                    harmonic_weights=c.tolist(), phases_rad=rng.uniform(0, 2 * np.pi, 3).tolist())
    if name == "payload":
        mass = _u(rng, lo, hi)
        com = [_u(rng, -0.03, 0.03), _u(rng, -0.03, 0.03), _u(rng, 0.02, 0.12)]
        dims = rng.uniform(0.04, 0.12, 3)
        Ib = mass / 12.0 * np.diag([dims[1] ** 2 + dims[2] ** 2, dims[0] ** 2 + dims[2] ** 2,
                                    dims[0] ** 2 + dims[1] ** 2])
        rot = pin.exp3(rng.normal(scale=0.5, size=3))
        inertia_rot = rot @ Ib @ rot.T
        return dict(mass_kg=mass, com_m=com, box_dims_m=dims.tolist(), inertia_kg_m2=inertia_rot.tolist())
    if name == "delay":
        return dict(delay_ms=_u(rng, lo, hi))
    if name == "friction_drift":
        mag = _u(rng, lo, hi)
        sign = -1.0 if rng.uniform() < 0.75 else 1.0
        shape = "linear" if rng.uniform() < 0.5 else "tanh"
        return dict(f=sign * mag, shape=shape, tau_w_frac=_u(rng, 0.15, 0.4))
    if name == "backlash":
        return dict(gap_rad=_u(rng, lo, hi), resonance_hz=_u(rng, 60, 120), zeta=_u(rng, 0.1, 0.3),
                    link_friction_share=_u(rng, 0.2, 0.4))
    raise ValueError(name)


def perturb_links(mode, rng):
    mass, com, inertia = LINK_MASS.copy(), LINK_COM.copy(), LINK_INERTIA.copy()
    rec = {}
    if mode == "nominal":
        return mass, com, inertia, rec
    if mode == "heavier_3_4":
        links = [2, 3]
        for i in links:
            ms = _u(rng, 1.05, 1.10)
            isc = _u(rng, 1.05, 1.10)
            dc = rng.uniform(-0.05, 0.05, 3) * np.abs(com[i]) + rng.uniform(-0.001, 0.001, 3)
            mass[i] *= ms
            inertia[i] *= isc
            com[i] = com[i] + dc
            rec[i + 1] = dict(mass_scale=ms, inertia_scale=isc, com_shift_m=dc.tolist())
    elif mode == "random_10pct":
        for i in range(1, 7):
            ms = _u(rng, 0.9, 1.1)
            isc = _u(rng, 0.9, 1.1)
            dirn = rng.normal(size=3)
            dirn /= np.linalg.norm(dirn)
            dc = dirn * rng.uniform(0, 1) * (0.1 * np.linalg.norm(com[i]) + 0.002)
            mass[i] *= ms
            inertia[i] *= isc
            com[i] = com[i] + dc
            rec[i + 1] = dict(mass_scale=ms, inertia_scale=isc, com_shift_m=dc.tolist())
    else:
        raise ValueError(mode)
    return mass, com, inertia, rec



def _friction_truth(rng):
    return dict(Fc_pos=T41_FC_POS * rng.uniform(0.85, 1.15, N), Fc_neg=T41_FC_NEG * rng.uniform(0.85, 1.15, N),
                B_pos=T41_B_POS * rng.uniform(0.8, 1.2, N), B_neg=T41_B_NEG * rng.uniform(0.8, 1.2, N))



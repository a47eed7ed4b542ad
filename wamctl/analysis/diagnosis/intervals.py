"""95 % intervals of the parameters of every effect kept at a joint, and the ones the data cannot determine
(no I/O; the statistics are in :mod:`wamctl.analysis.diagnosis.uncertainty`)."""

from __future__ import annotations

import numpy as np
from scipy import stats

from wamctl.analysis.diagnosis.candidates import DELAY_GRID_S, DRIFT_T_GRID_FRACTION, STRIBECK_VS_GRID_RAD_S
from wamctl.analysis.diagnosis.design import N_FRICTION, ncols, target_and_design
from wamctl.analysis.diagnosis.parameters import kept_effect_params, ripple_params
from wamctl.analysis.diagnosis.stats import effective_tau, lstsq
from wamctl.analysis.diagnosis.uncertainty import LEVEL, N_BOOT, group_bootstrap, percentile_ci, profile_ci

SHAPE_KEY = {"stribeck": "vs_rad_s", "position_ripple": "period_rad", "delay": "delay_s",
             "friction_drift": "time_constant_s"}
N_BOOT_ONSETS = 60           # onset bootstraps integrate the joint through every stall: fewer replicates


def _numeric(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def joint_intervals(diag, j: int) -> dict:
    """{effect name: {"params_ci": {key: [low, high]}, "not_identified": [keys]}} of every effect kept at 0-based
    joint ``j`` of a fitted ``ModelDiagnosis`` (the arm's payload is :func:`...arm.payload_uncertainty`'s)."""
    res, jd, des = diag.joints_[j], diag.jd_[j], diag.design_
    if not res.kept:
        return {}
    y, X = target_and_design(des, jd, res.kept, None)
    reps = group_bootstrap(X, y, jd.extra["block"], N_BOOT, np.random.default_rng(1000 + j))
    e = res.e_after[np.isfinite(res.e_after)]
    n_eff = len(e) / max(effective_tau(res.e_after, jd.fold), 1.0)
    out = {}
    for i, t in enumerate(res.kept):
        name = t["name"]
        if name in ("payload", "link_parameters"):       # the arm's: their intervals come with the arm's fit
            continue
        base = kept_effect_params(diag, j, name)
        samples = [kept_effect_params(diag, j, name, th) for th in reps]
        nb = len(np.unique(jd.extra["block"]))
        if name == "position_ripple":
            samples = [_phases_near(s, base) for s in samples]
        ci = {k: percentile_ci([s.get(k) for s in samples], center=v, n_groups=nb) for k, v in base.items()
              if _numeric(v) and np.ptp([s.get(k, v) for s in samples]) > 0}
        ni = []
        key = SHAPE_KEY.get(name)
        if isinstance(t.get("fixed_h"), tuple):           # a Stribeck shape measured at onsets or on the map
            ci.update(_stribeck_elsewhere_ci(diag, j, t, samples, base))
            for key, sgn in (("pos", 1.0), ("neg", -1.0)):
                if not (np.sign(jd.qd_rad_s) == sgn).any():   # no sliding sample that way: the fit's bound, 0
                    ci[f"Fc_{key}_Nm"] = [None, None]
            if not t.get("seen", "").startswith("on the friction map"):
                # its velocity was fitted to the sliding samples (with the ratios measured at the onsets)
                rp, rn, vs, delta = t["fixed_h"]
                grid = _profile_grid(des, "stribeck", vs)
                ssr = [_ssr_with(des, jd, res.kept, i, (rp, rn, float(h), delta)) for h in grid]
                lo, hi = profile_ci(grid, ssr, n_eff)
                ci["vs_rad_s"] = [None if lo is None else min(lo, vs), None if hi is None else max(hi, vs)]
        elif key:
            h0 = float(t["h_all"][0] if name == "position_ripple" else t["h_all"])
            grid = _profile_grid(des, name, h0)
            # a ripple's period is profiled with its number of harmonics fixed
            ssr = [_ssr_with(des, jd, res.kept, i, (h, t["h_all"][1]) if name == "position_ripple" else h)
                   for h in grid]
            if name == "position_ripple":          # a sharp profile: resolved where it crosses the threshold
                grid, ssr = _zoom_profile(grid, ssr, n_eff, lambda h, i=i, nh=t["h_all"][1]: _ssr_with(
                    des, jd, res.kept, i, (h, nh)))
            lo, hi = profile_ci(grid, ssr, n_eff)
            if (lo, hi) != (None, None):      # the estimate is in its interval (a grid's resolution aside)
                lo = None if lo is None else min(lo, h0)
                hi = None if hi is None else max(hi, h0)
            ci[key] = [lo, hi]
            if name == "position_ripple":
                _ripple_over_period(des, jd, res.kept, i, ci)
            if name == "friction_drift" and hi is None:
                # a time constant beyond what the run can tell (the drift is linear over it): the fraction it
                # drifts to is not determined either, only its change over the run
                ci["fraction"] = [None, None]
        if name == "backlash":
            ci["width_rad"] = _backlash_ci(diag.onsets_.get(j, {}))
        for k, v in ci.items():
            if k.startswith(("Fc_", "Fs_", "amplitude", "rms_")) and v[0] is not None:
                v[0] = max(v[0], 0.0)                     # friction levels and ripple amplitudes are magnitudes
            if k.startswith("phase") and None not in v and v[1] - v[0] >= 2 * np.pi:
                ci[k] = v = [None, None]                  # an arc of a whole turn: any phase fits the data
            if v == [None, None] and k in base and _numeric(base[k]):
                ni.append(k)
        out[name] = {"params_ci": ci, "not_identified": ni}
    return out


def _phases_near(sample: dict, base: dict) -> dict:
    """A bootstrap replicate of a ripple's parameters with each phase taken within pi of the estimate's (a phase
    is an angle: its interval is the arc around the estimate, its ends may lie below 0 or above 2 pi)."""
    out = dict(sample)
    for k, v in sample.items():
        if k.startswith("phase") and _numeric(v) and _numeric(base.get(k)):
            out[k] = base[k] + (v - base[k] + np.pi) % (2 * np.pi) - np.pi
    return out


def _ripple_over_period(des, jd, terms: list[dict], i: int, ci: dict) -> None:
    """Widen the intervals of a ripple's amplitudes and phases (term ``i`` of ``terms``, bootstrapped at its
    period) to the values they take at the ends of the period's interval: a phase is referred to the angle 0,
    so the period's uncertainty moves it by ``2 pi h q / P`` times the period's relative change."""
    period, nh = terms[i]["h_all"]
    k = N_FRICTION + sum(ncols(t) for t in terms[:i])
    for p in ci.get("period_rad", [None, None]):
        if p is None:
            continue
        y, X = target_and_design(des, jd, [dict(t, h_all=(p, nh)) if n == i else t for n, t in enumerate(terms)],
                                 None)
        for key, v in ripple_params(lstsq(X, y)[k:k + 2 * nh], (p, nh)).items():
            if key == "period_rad" or key not in ci or None in ci[key]:
                continue
            lo, hi = ci[key]
            if key.startswith("phase"):     # an angle: the value nearest the interval's middle
                v = (lo + hi) / 2 + (v - (lo + hi) / 2 + np.pi) % (2 * np.pi) - np.pi
            ci[key] = [min(lo, v), max(hi, v)]


def _zoom_profile(hs, ssr, n_eff: float, ssr_of, rounds: int = 4, points: int = 9) -> tuple[np.ndarray,
                                                                                              np.ndarray]:
    """A profile (values ``hs``, SSRs ``ssr``) evaluated again, ``points`` values at a time, between the values
    just outside the interval, until the interval spans five values (at most ``rounds`` times); then at each end
    where the statistic crosses the threshold (linear between the last value inside and the first outside)."""
    crit = stats.chi2.ppf(LEVEL, 1)

    def inside_of(hs, ssr):
        o = np.argsort(hs)
        hs, ssr = hs[o], ssr[o]
        return hs, ssr, np.flatnonzero(n_eff * np.log(ssr / ssr.min()) <= crit)

    hs, ssr, inside = inside_of(np.asarray(hs, float), np.asarray(ssr, float))
    for _ in range(rounds):
        if len(inside) >= 5:
            break
        new = np.linspace(hs[max(inside[0] - 1, 0)], hs[min(inside[-1] + 1, len(hs) - 1)], points)[1:-1]
        hs, ssr, inside = inside_of(np.r_[hs, new], np.r_[ssr, [ssr_of(h) for h in new]])
    stat = n_eff * np.log(ssr / ssr.min())
    ends = []
    for a, b in ((inside[0], inside[0] - 1), (inside[-1], inside[-1] + 1)):
        if 0 <= b < len(hs) and stat[b] > stat[a]:
            ends.append(hs[a] + (hs[b] - hs[a]) * (crit - stat[a]) / (stat[b] - stat[a]))
    hs, ssr, _ = inside_of(np.r_[hs, ends], np.r_[ssr, [ssr_of(h) for h in ends]])
    return hs, ssr


def _profile_grid(des, name: str, h: float) -> np.ndarray:
    """Shape values the profile likelihood is evaluated at: the candidate's grid and a fine one around ``h``."""
    if name == "delay":
        g = np.r_[DELAY_GRID_S, h + np.linspace(-2e-3, 2e-3, 41)]
        g = g[(g >= DELAY_GRID_S[0]) & (g <= DELAY_GRID_S[-1])]
    elif name == "stribeck":
        g = np.r_[STRIBECK_VS_GRID_RAD_S, np.geomspace(h / 4, h * 4, 41)]
        g = g[(g >= STRIBECK_VS_GRID_RAD_S[0]) & (g <= STRIBECK_VS_GRID_RAD_S[-1])]
    elif name == "position_ripple":
        g = h * (1 + np.linspace(-0.1, 0.1, 41))        # then zoomed where it crosses the threshold
    else:
        T = DRIFT_T_GRID_FRACTION * max(des.sig.duration_s, 1e-3)
        g = np.r_[T, np.geomspace(h / 3, h * 3, 41)]
        g = g[(g >= T[0]) & (g <= T[-1])]
    return np.unique(np.r_[g, h])


def _ssr_with(des, jd, terms: list[dict], i: int, h) -> float:
    """Residual sum of squares of the final model on all data with term ``i``'s shape set to ``h``."""
    ts = [dict(t) for t in terms]
    ts[i]["h_all"] = h
    if isinstance(h, tuple):
        ts[i]["fixed_h"] = h
    y, X = target_and_design(des, jd, ts, None)
    r = y - X @ lstsq(X, y)
    return float(r @ r)


def _stribeck_elsewhere_ci(diag, j: int, term: dict, samples: list[dict], base: dict) -> dict:
    """Intervals of a Stribeck effect whose shape was measured at the breakaways or on the friction map: the
    breakaway ratios and the velocity by a bootstrap over the onsets (or the map's segments), the Coulomb levels
    from the block bootstrap (``samples``)."""
    rng = np.random.default_rng(2000 + j)
    fc_pos = np.array([s["Fc_pos_Nm"] for s in samples])
    fc_neg = np.array([s["Fc_neg_Nm"] for s in samples])
    mp = (getattr(diag, "map_tests_", {}) or {}).get(j)
    ratios, vss = [], []
    if term.get("seen", "").startswith("on the friction map") and mp is not None:
        from wamctl.analysis.diagnosis.sweeps import map_bootstrap

        ratios, vss = map_bootstrap(mp, N_BOOT_ONSETS, rng)
    else:
        ons = term.get("onsets") or diag.onsets_.get(j) or {}
        ratios, vss = _onset_ratio_bootstrap(diag, ons, N_BOOT_ONSETS, rng)
    out = {"Fs_pos_Nm": [None, None], "Fs_neg_Nm": [None, None]}
    if ratios:
        k = min(len(ratios), len(fc_pos))
        rp = np.array([r[0] for r in ratios[:k]])
        rn = np.array([r[1] for r in ratios[:k]])
        out = {"Fs_pos_Nm": percentile_ci(rp * fc_pos[:k], center=base["Fs_pos_Nm"]),
               "Fs_neg_Nm": percentile_ci(rn * fc_neg[:k], center=base["Fs_neg_Nm"])}
    if vss:
        out["vs_rad_s"] = percentile_ci(vss, center=base["vs_rad_s"])
    # levels measured in N m at the onsets (the estimate then): their onsets resampled
    from wamctl.analysis.diagnosis.onsets import level_bootstrap

    for key, boot in level_bootstrap(term.get("breakaway_levels_Nm") or {}, N_BOOT_ONSETS, rng).items():
        out[f"Fs_{key}_Nm"] = percentile_ci(boot, center=base[f"Fs_{key}_Nm"])
    return out


def _onset_ratio_bootstrap(diag, ons: dict, n_boot: int, rng) -> tuple[list, list]:
    """Breakaway ratios per direction over onsets resampled with replacement (no velocity: that one is fitted
    to the sliding samples, its interval is a profile's)."""
    r = ons.get("breakaway_ratio")
    if r is None or len(r) < 4:
        return [], []
    use = np.flatnonzero(np.isfinite(r))
    if len(use) < 4:
        return [], []
    ratios, vss = [], []
    for _ in range(n_boot):
        pick = rng.choice(use, size=len(use), replace=True)
        per = []
        for sgn in (1.0, -1.0):
            m = pick[ons["sign"][pick] == sgn]
            g = np.exp(np.mean(np.log(r[pick])))
            per.append(float(np.exp(np.mean(np.log(r[m])))) if len(m) >= 2 else float(g))
        ratios.append(tuple(per))
    return ratios, vss


def _backlash_ci(ons: dict) -> list[float | None]:
    """Interval of the dead band (:func:`~wamctl.analysis.diagnosis.backlash.band_width`) over onsets resampled
    with replacement (reversals and same-direction onsets resampled apart; onsets where the model's link never
    moved left out, as in the test), widened for the few reversals resampled; of its magnitude (a gap on the motor
    side has a negative band)."""
    from wamctl.analysis.diagnosis.backlash import band_width

    d, rev = ons.get("travel_rad"), ons.get("reversal")
    if d is None or rev is None:
        return [None, None]
    d, rev = d[np.isfinite(d)], rev[np.isfinite(d)]
    if rev.sum() < 3:
        return [None, None]
    rng = np.random.default_rng(3000)
    idx_r, idx_s = np.flatnonzero(rev), np.flatnonzero(~rev)
    out = []
    for _ in range(N_BOOT):
        pick = np.r_[rng.choice(idx_r, size=len(idx_r)), rng.choice(idx_s, size=len(idx_s)) if len(idx_s) else idx_s]
        out.append(band_width(d[pick], rev[pick]))
    w = band_width(d, rev)
    lo, hi = percentile_ci(out, center=w, n_groups=len(idx_r))
    if lo is None or hi is None:
        return [lo, hi]
    if w < 0:
        lo, hi = -hi, -lo
    return [max(lo, 0.0), hi]

"""Closing the loop of the model diagnosis: the model as a plant, and the closed-loop position check (no I/O).

* :func:`plant_dict` turns the declared or the augmented model of a fitted :class:`ModelDiagnosis` into a
  ``plant`` mapping in the :class:`wamctl.specs.PlantSpec` shape (``friction: {joints: ...}``, ``effects``,
  ``sensors``): :func:`model_file` wraps it as a model file (``format: wamctl-model/1``) that
  ``wamctl run`` accepts as ``plant: FILE``.
* :func:`position_check` scores both models on held-out data: the time blocks are split in two (even and
  odd); the models are refitted on one half (shape parameters kept), the run is simulated in windows of at
  most 20000 samples, each from the measured state at its start (the whole run up to ``max_samples``
  samples, else windows spread over it: :func:`check_windows`), and the other half is scored, then the other
  way round (above 20000 samples checked, only the odd half is scored, from models fitted on the even half).
  A joint that did not move in the samples checked is not scored (its error there would be zero, which says
  nothing). The closed loop itself (the run's reference and controller on a simulated arm built from a plant
  mapping) is a callable the caller hands in.

Documented approximations: a model file holds one parameter set per effect (one ripple period with its
harmonics, one drift time constant, one dead band, one Stribeck ratio and velocity) even when the diagnosis found
an effect at several joints with different parameters (the strongest joint's set is written); joints that did not
move keep the declared friction (Table 4.1, or the given model file's).
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from wamctl.analysis.diagnosis.backlash import resolution_rad
from wamctl.analysis.diagnosis.candidates import ripple_harmonics
from wamctl.analysis.diagnosis.design import block_of, levels_dict, model_levels
from wamctl.analysis.diagnosis.signals import MIN_TRAVEL_RAD
from wamctl.control.controllers import pid_torque_series_Nm
from wamctl.io import MODEL_FILE_FORMAT
from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.effects import friction_drift_scale
from wamctl.model.friction import FrictionModel
from wamctl.specs import PlantSpec

log = logging.getLogger(__name__)

WINDOW_SAMPLES = 20000           # a simulation of the position check runs this long at most, then restarts
MAX_SIM_SAMPLES = 100000         # per model: runs up to this long are checked whole, longer ones in windows spread
BOTH_HALVES_MAX = 20000          # up to this many samples checked both halves are scored (four simulations each)
SIM_THREADS = min(4, os.cpu_count() or 1)    # the position check's simulations run side by side on this many threads


def encoder_counts(q_raw: np.ndarray, joints: list[int]) -> int:
    """Encoder resolution the data look quantised with (4096 or 40960 counts per motor turn), or 0.

    A joint's smallest measured step is compared with the joint-space size of one motor count through
    ``J2MP`` (the smallest coupling entry of its row of ``J2MP^-1``)."""
    inv = np.abs(np.linalg.inv(P.J2MP))
    votes = {4096: 0, 40960: 0}
    for j in joints:
        obs = resolution_rad(q_raw[:, j], min_steps=20)
        if obs == 0:
            continue
        row = inv[j][inv[j] > 1e-12]
        for cpr in votes:
            if abs(obs / (2 * np.pi / cpr * row.min()) - 1) < 0.3:
                votes[cpr] += 1
    best = max(votes, key=votes.get)
    return best if votes[best] >= max(1, len(joints) // 2) else 0


def _clip(x, lo, hi):
    return float(min(max(x, lo), hi))


DRIFT_FRACTION_RANGE = (-0.9, 3.0)    # the plant's (specs.FrictionDriftEffect)


def plant_drift(fraction: float, time_constant_s: float, duration_s: float) -> tuple[float, float]:
    """(fraction, time constant) of a drift in the plant's range: a drift whose time constant lies far beyond the
    run (a linear one) may need a fraction beyond the range, which the data never see (friction would cross zero
    long after the run). Such a drift is written with the fraction at the end of the range and the time constant
    that gives the same change over the run."""
    lo, hi = DRIFT_FRACTION_RANGE
    f = _clip(fraction, lo, hi)
    T = max(float(time_constant_s), 1e-3)
    if f == fraction:
        return f, T
    change = float(friction_drift_scale(duration_s, fraction, T)) - 1.0     # the drift's change over the run
    if change / f >= 1.0:                                    # not reachable in range: the nearest
        return f, T
    return f, float(-duration_s / np.log1p(-change / f))


def plant_dict(diag, which: str = "after", thetas: dict | None = None) -> dict:
    """The declared (``which="before"``) or augmented (``"after"``) model as a ``plant`` mapping.

    Parameters
    ----------
    diag : a fitted :class:`wamctl.analysis.diagnosis.ModelDiagnosis`.
    thetas : coefficients from :meth:`ModelDiagnosis.refit` (default: fitted on all data).
    """
    declared = diag.declared_
    nj = diag.dynamics_.n_joints          # the run's arm
    base = declared.friction if declared.friction is not None else FrictionModel.table_4_1(nj)
    joints = {}
    for j in range(nj):
        d = levels_dict(model_levels(base, j))
        if j in diag.joints_:
            tb, ta = (thetas or {}).get(j, (None, None))
            fr = diag.friction_after(j, ta) if which == "after" else diag.friction_before(j, tb)
            d = {k: max(0.0, float(v)) for k, v in fr.items()}
        joints[j + 1] = d
    effects = dict(declared.effects or {})
    if which == "after":
        effects.update(_effects_after(diag, thetas, joints))
    sensors = dict(declared.sensors or {})
    sig = diag.signals_
    measured = sig.usable()          # not a gap's interpolated stretch (steps finer than a count)
    sensors.setdefault("encoder_counts_per_rev", sig.memo(
        "encoder_counts", lambda: encoder_counts(sig.q_raw_rad if measured.all() else sig.q_raw_rad[measured],
                                                 sig.joints)))        # (no copy of a log without gaps)
    out = {"friction": {"joints": joints}, "effects": effects, "sensors": sensors}
    if declared.links is not None:          # an identified arm (`wamctl identify`) stays the plant's rigid body
        out["links"] = declared.links.to_mapping()
    PlantSpec.model_validate(out)   # a programming error if this fails: the shape is ours
    return out


def _effects_after(diag, thetas, joints_friction) -> dict:
    found: dict[str, list[tuple[float, int, dict]]] = {}
    for j, res in diag.joints_.items():
        ta = (thetas or {}).get(j, (None, None))[1]
        for t in res.kept:
            params = diag.effect_params(j, t["name"], ta)
            found.setdefault(t["name"], []).append((t.get("gain", 0.0), j, params))
    out = {}
    for name, items in found.items():
        items.sort(key=lambda x: -x[0])
        gain, j, p = items[0]
        js = sorted(i[1] + 1 for i in items)
        if name == "stribeck":
            ratios, vss = [], []
            for _, jj, pp in items:
                fr = joints_friction[jj + 1]
                for fs, fc in ((pp["Fs_pos_Nm"], fr["fc_pos_Nm"]), (pp["Fs_neg_Nm"], fr["fc_neg_Nm"])):
                    if fc > 1e-9:
                        ratios.append(fs / fc)
                vss.append(pp["vs_rad_s"])
                fr.update(fs_pos_Nm=max(pp["Fs_pos_Nm"], 0.0), fs_neg_Nm=max(pp["Fs_neg_Nm"], 0.0),
                          vs_rad_s=_clip(pp["vs_rad_s"], 1e-4, 5.0),
                          stribeck_delta=_clip(pp.get("stribeck_delta", 2.0), 0.5, 4.0))
            out["stribeck"] = {"joints": js, "breakaway_ratio": _clip(np.median(ratios) if ratios else 1.5,
                                                                       1.0001, 10.0),
                               "vs_rad_s": _clip(float(np.median(vss)), 1e-4, 5.0),
                               "delta": _clip(float(p.get("stribeck_delta", 2.0)), 0.5, 4.0)}
        elif name == "position_ripple":
            amps, phases = ripple_harmonics(p)
            out["position_ripple"] = {"joints": [j + 1], "amplitude_Nm": _clip(amps[0], 1e-6, 20.0),
                                      "period_rad": _clip(p["period_rad"], 0.005, 6.3),
                                      "phase_rad": float(phases[0])}
            if len(amps) > 1:         # the harmonics (a one-sinusoid ripple writes the model file as before)
                out["position_ripple"]["harmonics"] = [{"amplitude_Nm": _clip(a, 0.0, 20.0), "phase_rad": float(ph)}
                                                       for a, ph in zip(amps[1:], phases[1:])]
        elif name == "payload":
            pl = thetas.get("payload") if thetas and thetas.get("payload") else diag.payload_ or p
            if pl and pl["mass_kg"] > 0:
                out["payload"] = {"mass_kg": _clip(pl["mass_kg"], 1e-6, 5.0),
                                  "com_m": [float(x) for x in pl["com_m"]]}
        elif name == "delay":
            out["delay"] = {"delay_s": _clip(float(np.median([i[2]["delay_s"] for i in items])), 1e-6, 0.1)}
        elif name == "friction_drift":
            f, T = plant_drift(p["fraction"], p["time_constant_s"], diag.signals_.duration_s)
            out["friction_drift"] = {"joints": [j + 1], "fraction": f, "time_constant_s": T}
        elif name == "backlash" and p.get("encoder_side", "link") == "link":
            # the plant's backlash is a dead band between link and encoder; a gap on the motor side (the
            # measurement leads the link) it cannot represent (said in the diagnosis' warnings)
            out["backlash"] = {"joints": [j + 1], "width_rad": _clip(p["width_rad"], 1e-7, 0.1)}
    return out


NOT_IDENTIFIED_NOTE = ("the parameters under not_identified were not determined by the data (the diagnosis "
                       "reports no value and no interval for them); the model holds the values the fit left there "
                       "so that it runs: they are not estimates")


def not_identified_params(summary: dict) -> dict[str, list[str]]:
    """{effect name: its parameters the data did not determine, over every joint that named it} of a diagnosis
    summary (:meth:`~wamctl.analysis.diagnosis.estimator.ModelDiagnosis.to_dict`), for the effects it kept."""
    out: dict[str, set] = {}
    for res in (summary.get("joints") or {}).values():
        for e in res.get("effects", []):
            if e.get("not_identified"):
                out.setdefault(e["name"], set()).update(e["not_identified"])
    return {k: sorted(v) for k, v in out.items()}


def model_file(diag, data_path: str = "", summary: dict | None = None) -> dict:
    """The augmented model as a model file (``format: wamctl-model/1``) with the diagnosis summary (``summary``:
    ``diag.to_dict(data_path)`` where the caller has it already). A model runs only with every parameter set, so
    an effect's parameters the data did not determine are written as the fit left them and listed under
    ``diagnosis.not_identified`` with :data:`NOT_IDENTIFIED_NOTE` (as ``wamctl identify``'s model file lists its
    undetermined base parameters)."""
    plant = plant_dict(diag, "after")
    robot = diag.dynamics_.robot.name
    summary = diag.to_dict(data_path) if summary is None else summary
    undetermined = {k: v for k, v in not_identified_params(summary).items() if k in plant.get("effects", {})}
    return {"format": MODEL_FILE_FORMAT, **({"robot": robot} if robot != "wam7" else {}), **plant,
            "diagnosis": {"data": data_path, "effects_found": list(diag.effects_found_),
                          "declared_model": summary["declared_model"],
                          **({"not_identified": undetermined, "note": NOT_IDENTIFIED_NOTE} if undetermined else {})}}


def feedforward_from_log(meta, t_s, q_ref, q, tau, gravity) -> np.ndarray | None:
    """Feed-forward torque of a ``pd_g_ff`` run recovered from the log: what the controller added to its PD
    and gravity terms (libbarrett's discrete law, see :mod:`wamctl.control.controllers`)."""
    if meta.controller.kind != "pd_g_ff":
        return None
    dt = float(np.median(np.diff(t_s)))
    pd = pid_torque_series_Nm(q_ref, q, meta.controller.kp, meta.controller.kd, np.zeros(q.shape[1]), dt)
    g = np.array([gravity(qi) for qi in q]) if gravity is not None else 0.0
    return tau - pd - g


def check_windows(sig, window: int = WINDOW_SAMPLES, budget: int = MAX_SIM_SAMPLES) -> list[tuple[int, int]]:
    """The stretches ``[(start, stop), ...]`` of the run the position check simulates, each from the measured
    state at its start: the whole run, cut into windows of at most ``window`` samples, when it has at most
    ``budget`` samples; else ``budget // window`` windows spread evenly from the start to the end of the run.
    Every window after the first starts where the arm is slowest within a quarter of a window (the last quarter
    of the window before it, or around the even spacing; the restart takes the measured position and smoothed
    velocity there: near rest, the state is known best)."""
    n = sig.n
    window = max(min(int(window), int(budget)), 10)
    v_stick = np.maximum(sig.v_stick_rad_s, 1e-6)[None, :]

    def restful(a: int, b: int) -> int:          # the slowest sample in [a, b), speed in stick thresholds
        b = min(max(b, a + 1), n)
        return a + int(np.argmin(np.max(np.abs(sig.qd_rad_s[a:b]) / v_stick, axis=1)))

    if n <= budget:
        bounds, a = [], 0
        while n - a > window:
            b = restful(a + 3 * window // 4, a + window)
            bounds.append((a, b))
            a = b
        return bounds + [(a, n)]
    k = max(1, budget // window)
    out = []
    for s0 in np.linspace(0, n - window, k).astype(int):
        s = 0 if s0 == 0 else restful(int(s0) - window // 8, min(int(s0) + window // 8, n - window) + 1)
        out.append((s, s + window))
    return out


def position_check(diag, data, simulate_positions, max_samples: int = MAX_SIM_SAMPLES, meta=None,
                   window: int = WINDOW_SAMPLES) -> dict:
    """Held-out closed-loop position error of the declared and the augmented model.

    ``simulate_positions(plant, meta, t_s, q_ref, q0, feedforward, payload, qd0=, t0_s=) -> (n, 7)`` runs the
    closed loop of a plant mapping from the state ``q0``, ``qd0`` at time ``t0_s`` (see
    :func:`wamctl.experiments.diagnose.simulate_positions`); the analysis never builds a simulator itself. The
    stretches simulated are :func:`check_windows` (``max_samples`` per model, ``window`` per simulation).

    Returns
    -------
    dict with ``t_s`` (m,), ``q_meas``, ``q_before``, ``q_after`` (m, 7) held-out traces over the samples checked
    (each sample simulated by the model not fitted on its block), ``rms_before`` / ``rms_after`` {0-based joint:
    rad} (NaN for a joint not checked), ``not_checked`` {0-based joint: why}, ``spans_s`` [[t_start, t_end], ...]
    of the windows, ``samples`` (checked) and ``samples_run``.
    """
    sig = diag.signals_
    spans = check_windows(sig, window, max_samples)
    rows = np.concatenate([np.arange(a, b) for a, b in spans])
    m = len(rows)
    t_run = sig.t_s
    # halves per joint: every other block of the joint's own sliding samples (see ModelDiagnosis: a joint that
    # moves in one part of the run only still has both halves); run samples take the half of their block
    half_fit, half_t = {}, {}
    for j, jd in diag.jd_.items():
        half_fit[j] = jd.extra["block"] % 2
        half_t[j] = block_of(jd, t_run[rows]) % 2
    meta = meta or diag.meta_    # the run's metadata, with the controller's gains the check uses
    mp = meta.payload            # what the controller's gravity compensation knew
    ctl_payload = Payload(mp.mass_kg, tuple(mp.com_m)) if mp is not None and mp.mass_kg > 0 else None
    dyn = WamDynamics(ctl_payload, robot=diag.dynamics_.robot)
    nj = dyn.n_joints
    gravity = dyn.gravity if meta.gravity_compensation else None
    ffs = [feedforward_from_log(meta, t_run[a:b], sig.q_ref_rad[a:b], sig.q_raw_rad[a:b], sig.tau_raw_Nm[a:b],
                                gravity) for a, b in spans]
    traces = {"before": np.full((m, nj), np.nan), "after": np.full((m, nj), np.nan)}
    same = not diag.effects_found_
    starts = np.cumsum([0] + [b - a for a, b in spans])        # each window's first row among ``rows``

    def simulate(plant: dict, k: int) -> np.ndarray:
        a, b = spans[k]
        # the first window starts as the run does (at rest); later ones from the measured state
        qd0 = None if a == 0 else sig.qd_rad_s[a]
        return simulate_positions(plant, meta, t_run[a:b], sig.q_ref_rad[a:b], sig.q_raw_rad[a], ffs[k],
                                  ctl_payload, qd0=qd0, t0_s=float(t_run[a] - t_run[0]))

    # up to BOTH_HALVES_MAX samples checked, both halves are scored (four simulations); above, one half (two)
    models = []
    for h in ((0, 1) if m <= BOTH_HALVES_MAX else (1,)):
        if not any((half == h).any() for half in half_t.values()):
            continue        # no sample of this half in the windows simulated (a long run's first block)
        thetas = diag.refit(lambda jd, h=h: half_fit[jd.j] != h)       # fit on the other half
        models += [(h, which, plant_dict(diag, which, thetas)) for which in ("before", "after")
                   if not (which == "after" and same)]
    # every window of every model is its own simulation from its own start state: they run side by side (the
    # compiled loop releases the interpreter), each writing its own rows, so the traces are those of one by one
    jobs = [(i, k) for i in range(len(models)) for k in range(len(spans))]
    workers = min(len(jobs), SIM_THREADS)
    if workers > 1:
        with ThreadPoolExecutor(workers) as pool:
            sims = list(pool.map(lambda job: simulate(models[job[0]][2], job[1]), jobs))
    else:
        sims = [simulate(models[i][2], k) for i, k in jobs]
    for (i, k), q_win in zip(jobs, sims):           # in the order of the loop one by one (a later model wins)
        h, which = models[i][0], models[i][1]
        rows_k = slice(starts[k], starts[k + 1])
        for j in range(nj):
            sel = half_t[j][rows_k] == h if j in half_t else np.ones(len(q_win), bool)
            traces[which][rows_k][sel, j] = q_win[sel, j]
    if same:
        traces["after"] = traces["before"].copy()
    q_meas = sig.q_raw_rad[rows]
    rms_b, rms_a, not_checked = {}, {}, {}
    away = sig.usable(rows)             # the log's gaps are interpolated, not measured: not scored
    for j in diag.joints_:
        scored = away & np.isfinite(traces["before"][:, j])
        travel = float(np.ptp(q_meas[scored, j])) if scored.any() else 0.0
        if travel < MIN_TRAVEL_RAD:
            # a joint that stood still where it was checked: a zero error there says nothing about the model
            not_checked[j] = (f"did not move in the span checked (travel {travel:.4f} rad, at least "
                              f"{MIN_TRAVEL_RAD} rad needed)")
            rms_b[j] = rms_a[j] = float("nan")
            continue
        for which, store in (("before", rms_b), ("after", rms_a)):
            err = np.where(away, traces[which][:, j] - q_meas[:, j], np.nan)
            store[j] = float(np.sqrt(np.nanmean(err ** 2))) if np.isfinite(err).any() else float("nan")
    spans_s = [[float(t_run[a] - t_run[0]), float(t_run[b - 1] - t_run[0])] for a, b in spans]
    return {"t_s": t_run[rows], "q_meas": q_meas, "q_before": traces["before"], "q_after": traces["after"],
            "rms_before": rms_b, "rms_after": rms_a, "not_checked": not_checked, "spans_s": spans_s,
            "samples": m, "samples_run": sig.n}

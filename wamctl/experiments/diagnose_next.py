"""``wamctl diagnose``'s next experiment for a delay against an inertia error (issue 28 item 1): when a run's
residual holds an effect that a measurement delay and joint inertia errors explain alike, the excitation that
parts them best (:func:`wamctl.analysis.diagnosis.delay_inertia.design_next_run`) written as
``next_experiment.yaml``; when the run tells them apart, the decision."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def next_experiment_delay(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """The delay-or-inertia check of a fitted diagnosis (:func:`~wamctl.analysis.diagnosis.delay_inertia.
    check_run`). None when the diagnosis leaves no room for either (:func:`delay_or_inertia_suspected`) or the
    residual holds no effect either explains (by at least the noise floor beyond friction). Decided on this run:
    ``{"spec": None, "hypotheses", "decision", "why"}``. Ambiguous: the designed run written as
    ``out_dir/next_experiment.yaml`` (an excitation spec for the run's backend, plant and controller when the run
    directory names them) and ``{"spec", "hypotheses", "decision", "separation_noise_floors",
    "original_separation_noise_floors", "joints", "period_s", "noise_floor_Nm", "why", "candidates"}``."""
    import yaml

    from wamctl.analysis.diagnosis import delay_inertia as DI
    from wamctl.analysis.identification.excitation import ExcitationLimits
    from wamctl.experiments.excitation import designed_spec
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.friction import FrictionModel
    from wamctl.specs.excitation import ExcitationLimitsSpec

    if not (diag.joints_ and delay_or_inertia_suspected(diag)):
        return None
    dyn = WamDynamics(diag.payload_declared_, diag.declared_.links)
    chk = DI.check_run(diag, dyn)
    if not chk.suspected:
        return None
    dec = chk.decision
    base = {"hypotheses": ["delay", "inertia"], "decision": dec}
    if dec["outcome"] != "ambiguous":
        return dict(base, spec=None, why="none needed, " + DI.decision_line(dec))
    noise = chk.floors
    lim = ExcitationLimitsSpec()
    limits = ExcitationLimits(*lim.arrays(), 1 - lim.torque_margin, lim.max_cartesian_speed_m_s)
    q0 = np.array([0.0 if v is None else float(v) for v in data.meta.q0])
    ran = sorted(chk.rows.joints)
    sets = [ran, sorted(set(ran) | {3}), sorted(set(ran) | {1, 3}), list(range(7))]
    sets = [s for k, s in enumerate(sets) if s not in sets[:k]]
    friction = diag.declared_.friction or FrictionModel.table_4_1()
    try:
        nr = DI.design_next_run(dyn, friction, q0, chk.hyp, noise, chk.rows, limits, sets, seed=seed)
    except ValueError as exc:       # no candidate within the limits at this q0: said, no spec written
        return dict(base, spec=None, why=f"{DI.decision_line(dec)}; no run designed to tell them: {exc} at the "
                                         "run's q0")
    raw = {"kind": "excitation", "name": f"next-{Path(data_path).name}", "seed": seed,
           "q0_rad": [float(x) for x in q0]}
    src = Path(data_path) / "spec.yaml"
    if src.is_file():       # our own run: the same arm, backend and (simulated) plant
        orig = yaml.safe_load(src.read_text()) or {}
        raw.update({k: orig[k] for k in ("backend", "plant", "controller") if k in orig})
    tr = nr.trajectory
    raw["excitation"] = {"joints": [j + 1 for j in tr.moving], "period_s": float(tr.period_s),
                         "harmonics": int(tr.harmonics), "periods": 3, "settle_s": 1.0}
    spec = designed_spec(raw, tr)
    sep, orig_sep = float(nr.separation["separation"]), float(nr.original["separation"])
    joints = ", ".join(str(j + 1) for j in tr.moving)
    why = (f"the run cannot tell a {dec['delay_s'] * 1e3:.1f} ms measurement delay from inertia errors of joints "
           f"{', '.join(str(j + 1) for j in ran)} (a delay times the viscous friction acts as an inertia at one "
           f"speed; separation {orig_sep:.2g} noise floors, {_floors(dec)}); moving joints {joints} with "
           f"{tr.harmonics} harmonics of a {tr.period_s:g} s period (several speeds: the delay's apparent damping "
           f"grows with the square of the frequency, an inertia error's does not) their predicted torques differ by "
           f"{sep:.2g} noise floors (RMS per sample, after each refits its own parameters; the floor of a joint "
           "the run did not move assumed in proportion to its torque limit)"
           + ("" if sep > DI.DESIGN_TARGET_FLOORS else
              f": still below {DI.DESIGN_TARGET_FLOORS:g}, a longer run is needed to tell them"))
    (Path(out_dir) / "next_experiment.yaml").write_text(
        f"# designed by wamctl diagnose: {why}\n" + yaml.safe_dump(spec, sort_keys=False))
    return dict(base, spec="next_experiment.yaml", separation_noise_floors=sep,
                original_separation_noise_floors=orig_sep, joints=[j + 1 for j in tr.moving],
                period_s=float(tr.period_s), noise_floor_Nm={j + 1: v for j, v in noise.items()}, why=why,
                candidates=[{"joints": js, "period_s": p, "separation_noise_floors": float(v)}
                            for js, p, v in nr.scored])


def delay_or_inertia_suspected(diag) -> bool:
    """The diagnosis leaves room for a delay or an inertia error: a delay named, a delay in an ambiguous group, or
    a structured residual left unexplained at a joint."""
    return ("delay" in diag.effects_found_ or any("delay" in g for g in diag.ambiguous_)
            or any(r.unexplained for r in diag.joints_.values()))


def _floors(dec: dict) -> str:
    """The measured noise floors in words."""
    return ", ".join(f"{v:.2g} N m at joint {j}" for j, v in sorted(dec["floor_Nm"].items()))

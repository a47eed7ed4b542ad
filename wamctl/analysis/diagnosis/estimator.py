"""Model diagnosis: from a measured run to the effect the declared model lacks, with evidence (no I/O).

Method
------
1. **Torque residual.** Positions are differentiated with a centred Savitzky-Golay filter and the logged torque
   is aligned (zero-order hold) and smoothed by the same filter (:mod:`wamctl.analysis.diagnosis.signals`).
   ``y = tau - rnea(q, qd, qdd)`` with the declared rigid body (+ armature, + a declared payload) is what
   friction and any missing effect must supply. Samples where a joint sticks, and the filter's reach around
   them, are left out: there the friction torque is static and unknown. A log of the controller's output
   (``torque: controller``: gravity compensation added downstream, not logged) is diagnosed at the joints whose
   gravity torque is constant over the run, the declared gravity added back
   (:mod:`wamctl.model.controller_torque`); the others are skipped with the reason, none left is an error.
2. **Declared model.** Per joint, classic friction per direction (Coulomb + viscous) is linear in its four
   parameters; it is fitted by least squares (unless a model file gives it).
3. **Held-out data.** Each joint's sliding samples (in time order) are cut into ``n_blocks`` contiguous
   blocks of equal size, dealt into ``n_folds`` folds (block ``b`` -> fold ``b % n_folds``). Every number
   called held-out comes from a model fitted on the other folds; every shape parameter of a candidate
   (Stribeck velocity, ripple period, delay, drift time constant) is chosen on the training folds only.
4. **Candidates.** One signature per effect name (:mod:`wamctl.analysis.diagnosis.candidates`). Each is
   tested as a nested model against the current model on the held-out residuals: an F-test whose sample
   count is deflated by the residual's integrated autocorrelation time, against the null hypothesis that the
   effect explains at most ``MIN_EFFECT`` (5 %) of the residual variance the declared model left (a
   minimum-effect test, so that very long records do not turn traces into effects), and the BIC change
   (:mod:`wamctl.analysis.diagnosis.stats`). The threshold is ``alpha / (joints x tests)`` (Bonferroni over
   every test of the run), so that a run with nothing missing reports nothing with probability at least
   about ``1 - alpha``. An effect must also be physically plausible: a breakaway between 1 and 10 times the
   Coulomb level; a ripple the same in both directions of motion; one payload for the arm (10 g to 10 kg
   within 0.5 m of the flange, fitted over every joint that shows it); one delay for the arm (longer than
   one sample period, inside the range searched, seen alike at half the joints or more); a dead band of at
   least two encoder steps. Forward selection: the best passing candidate (largest held-out gain) is added,
   the rest are tested again against the augmented model, until none passes; from the second step on, the
   minimum effect is a share of the declared model's residual, so that the imperfections of a strong
   effect's model are not named as further effects. Friction levels are fitted non-negative.
5. **Onsets.** Backlash (and Stribeck, when the joint sticks and slips so that few sliding samples remain)
   shows where a joint starts to move: the link travel the model predicts before the measurement moved (or how
   far the measurement led the model's link: an encoder on the motor side of a gap), and
   the breakaway level the joint withstood (:mod:`wamctl.analysis.diagnosis.onsets`), tested the same way
   on held-out onsets (:mod:`wamctl.analysis.diagnosis.onset_tests`).
6. **After.** All parameters (friction and the kept effects) are refitted; the held-out torque RMS and the
   residual whiteness (Ljung-Box on one sample per filter window) are reported before and after. A joint's own
   effect (Stribeck, ripple, drift, a dead band behind the encoder) stays only where it takes at least the
   minimum effect off the joint's whole held-out torque (sliding samples and stalls) against the model without
   it: its test saw part of the evidence only.

Where each step lives: data preparation in :mod:`.prepare`, design matrices in :mod:`.design`, held-out
residuals and shape parameters in :mod:`.crossval`, the forward selection of one joint in :mod:`.joint`, the
arm-wide payload and delay in :mod:`.arm`, onsets in :mod:`.onsets` and :mod:`.onset_tests`, parameters in
physical units in :mod:`.parameters`, ``diagnosis.json`` in :mod:`.serialise`; the closed-loop position check
and the model file in :mod:`wamctl.analysis.diagnosis.augmented`. This module runs the steps in order.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from wamctl.analysis.blas import single_threaded_blas
from wamctl.analysis.diagnosis.arm import (
    PAYLOAD_COM_BOX_M,
    delay_disagreements,
    fold_payloads,
    global_payload_terms,
    payload_fit,
    payload_inconsistency,
    payload_links_reason,
    payload_links_summary,
    payload_rejection,
    payload_uncertainty,
)
from wamctl.analysis.diagnosis.augmented import MAX_SIM_SAMPLES, position_check
from wamctl.analysis.diagnosis.candidates import ARM_ONLY, EFFECT_NAMES
from wamctl.analysis.diagnosis.crossval import cv_terms
from wamctl.analysis.diagnosis.delay_backlash import settle as delay_vs_gap
from wamctl.analysis.diagnosis.design import JointData, columns, fit_theta, target_and_design
from wamctl.analysis.diagnosis.honesty import against_declared, worse_warnings
from wamctl.analysis.diagnosis.joint import JointResult, forward_select, joint_baseline, set_after
from wamctl.analysis.diagnosis.onset_tests import onset_tests, stribeck_at_breakaways
from wamctl.analysis.diagnosis.parallel import adopt_caches, cache_keys, caches_since, joint_workers, map_in_order
from wamctl.analysis.diagnosis.parameters import (
    friction_levels_after,
    friction_levels_before,
    kept_effect_params,
    report_effects,
)
from wamctl.analysis.diagnosis.prepare import declared_delay_s, prepare_design
from wamctl.analysis.diagnosis.serialise import diagnosis_dict
from wamctl.analysis.diagnosis.signals import Signals, gap_warnings, prepare_signals, refuse_joints
from wamctl.analysis.diagnosis.stats import MIN_EFFECT, finite_ss
from wamctl.analysis.diagnosis.sweeps import friction_map_of, map_evidence
from wamctl.analysis.diagnosis.timing import rigid_body_shift_s, shift_rigid_body
from wamctl.analysis.diagnosis.unexplained import arm_unnamed, unexplained
from wamctl.errors import DataFormatError
from wamctl.model.controller_torque import constant_gravity
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.friction import FrictionModel
from wamctl.model.params import LinkParameters

log = logging.getLogger(__name__)

MIN_DECLARED_R2 = 0.25            # below: the data are not this arm under this model (garbage in)
NET_GAIN = float(np.sqrt(1.0 - MIN_EFFECT))   # a joint's own effect must take this much off its torque RMS


@dataclass
class DeclaredModel:
    """What the user declares: friction (None = fit it), a payload known to the model, effects from a model
    file (a PlantSpec ``effects`` mapping), the file's sensors and its link parameters (an identified arm,
    ``wamctl identify``; None: the datasheet), if any."""

    friction: FrictionModel | None = None
    payload: Payload | None = None
    effects: dict = field(default_factory=dict)
    sensors: dict | None = None
    source: str | None = None
    links: LinkParameters | None = None

    @property
    def fitted(self) -> bool:
        return self.friction is None

    @property
    def delay_s(self) -> float:
        """The declared measurement delay, s (0 without one)."""
        return declared_delay_s(self.effects)


def torque_warnings(sig: Signals, robot=None) -> list[str]:
    """Torques beyond the model's limits (``robot``'s, default the wam7's) are data (a real arm's log, another
    controller), not errors: said."""
    from wamctl.model.robots import get_robot

    limit = get_robot(robot).tau_max_Nm
    out = []
    for j in range(sig.tau_raw_Nm.shape[1]):        # joint by joint: no temporary the size of the whole log
        tau = np.abs(sig.tau_raw_Nm[:, j])
        over = int(np.count_nonzero(tau > limit[j] * (1 + 1e-6)))
        if over:
            out.append(f"joint {j + 1}: {over} samples with |tau| above the model's limit of "
                       f"{limit[j]:g} N m (up to {tau.max():.3g} N m); kept as data")
    return out


class ModelDiagnosis:
    """Find what the declared model of the WAM lacks in a measured run.

    Parameters
    ----------
    alpha : family-wise false-alarm level of the whole run (Bonferroni over joints x candidates).
    n_blocks, n_folds : contiguous time blocks and the folds they are dealt into.
    candidates : effect names to test (default: all of the vocabulary).
    declared : the declared model (default: classic friction fitted from the data).
    max_steps : effects kept per joint at most.
    window_s, gauss_s : Savitzky-Golay window and Gaussian pre-filter sigma of the differentiation filter.
    simulator : ``simulate_positions(plant, meta, t_s, q_ref, q0, feedforward, payload) -> (n, 7)``, the closed
        loop of a model on a simulated arm (:func:`wamctl.experiments.diagnose.simulate_positions`); given, the
        closed-loop position check runs (:mod:`wamctl.analysis.diagnosis.augmented`), None skips it.
    max_sim_samples : samples simulated per model in that check (the whole run up to this many, else windows
        spread over it: :func:`wamctl.analysis.diagnosis.augmented.check_windows`).
    jobs : worker processes the joints are diagnosed in (:mod:`wamctl.analysis.diagnosis.parallel`, the same
        diagnosis): None chooses (the CPUs available on a long run, else none), 1 none.

    Attributes (after ``fit``)
    --------------------------
    signals_ : :class:`Signals`.
    joints_ : {0-based joint: :class:`JointResult`}.
    effects_found_ : effect names kept anywhere, strongest first.
    conclusive_ : False when nothing could be concluded (reason in ``reason_``).
    threshold_ : per-test p-value threshold.
    design_ : :class:`wamctl.analysis.diagnosis.design.Design`, the run's arrays (also as ``rnea_full_``,
        ``known_``, ``known_other_``, ``union_``, ``decimation_``).
    jd_ : {0-based joint: :class:`wamctl.analysis.diagnosis.design.JointData`}.
    onsets_ : {0-based joint: its onsets (:func:`wamctl.analysis.diagnosis.onsets.joint_onsets`)}.
    payload_ : the arm's payload found (``mass_kg``, ``com_m``, ``joints_fitted``), else None.
    positions_ : the closed-loop position check, or None.
    workers_ : worker processes the joints were diagnosed in (1: none, this process).
    """

    def __init__(self, *, alpha: float = 0.01, n_blocks: int = 10, n_folds: int = 5,
                 candidates: tuple[str, ...] = EFFECT_NAMES, declared: DeclaredModel | None = None,
                 max_steps: int = 3, window_s: float | None = None, gauss_s: float | None = None,
                 simulator=None, max_sim_samples: int | None = None, jobs: int | None = None):
        self.alpha = alpha
        self.n_blocks = n_blocks
        self.n_folds = n_folds
        self.candidates = candidates
        self.declared = declared
        self.max_steps = max_steps
        self.window_s = window_s
        self.gauss_s = gauss_s
        self.simulator = simulator
        self.max_sim_samples = max_sim_samples
        self.jobs = jobs

    # ------------------------------------------------------------------------------------------ fit
    def fit(self, data, progress=None) -> ModelDiagnosis:
        """Diagnose a :class:`wamctl.runs.measured.RunData` (a run directory or a measured run, loaded).
        ``progress(fraction, label)``, when given, is told how far the diagnosis is (0..1) and what it does."""
        self._progress = progress or (lambda fraction, label: None)
        with single_threaded_blas():
            return self._fit(data)

    def _fit(self, data) -> ModelDiagnosis:
        self._progress(0.0, "preparing the signals")
        declared = self.declared or DeclaredModel()
        self.declared_ = declared
        self.meta_ = data.meta
        self.source_ = getattr(data, "source", None)      # the run directory (its physics' timing: diagnosis.timing)
        self.conclusive_ = False
        self.reason_ = None
        self.joints_ = {}
        self.effects_found_ = []
        self.ambiguous_ = []
        self.arm_unnamed_ = []
        self.payload_dropped_ = None
        self.payload_cone_fit_ = None
        self.friction_map_ = None        # made on first use for this run's joints (sweeps.friction_map_of)
        self.warnings_ = []
        self.gains_ = None
        self.position_skipped_ = None
        self.workers_ = 1
        unknown = [c for c in self.candidates if c not in EFFECT_NAMES]
        if unknown:
            raise ValueError(f"unknown candidate effects {unknown}; known: {EFFECT_NAMES}")
        sig = self._signals(data)
        self.warnings_ = gap_warnings(sig) + torque_warnings(sig, self.dynamics_.robot)
        for w in self.warnings_:
            log.warning(w)
        if not sig.joints:
            why = "; ".join(f"joint {j + 1}: {r}" for j, r in sig.skipped.items())
            self.reason_ = ("no joint moved enough to compare the model with the data"
                            + (f" ({why})" if why else ""))
            log.warning(self.reason_)
            return self
        self.declared_effects_ = set(declared.effects or {})
        self._prepare(sig)
        tests = [c for c in self.candidates if c not in self.declared_effects_]
        # every test of the run: one per joint and candidate, and Stribeck three times (sliding data,
        # breakaways, friction map)
        n_tests = len(tests) + (2 if "stribeck" in tests else 0)
        self.map_tests_ = {}
        self.threshold_ = self.alpha / max(1, len(sig.joints) * max(1, n_tests))
        torque_tests = [c for c in tests if c != "backlash" and c not in ARM_ONLY]
        self.rejected_ = {j: {} for j in sig.joints}     # candidates an arm-wide check ruled out, with why
        self.arm_ambiguous_ = {j: [] for j in sig.joints}   # ambiguous groups an arm-wide check left at a joint
        self._diagnose_joints(sig.joints, torque_tests)
        self._progress(0.6, "arm-wide checks")
        r2 = self._declared_r2()
        if r2 < MIN_DECLARED_R2 and self._rigid_body_r2() < MIN_DECLARED_R2:
            self.reason_ = (f"the declared model explains only {max(r2, 0.0):.0%} of the torque of the moving "
                            f"joints (at least {MIN_DECLARED_R2:.0%} expected, also with a wrist payload and link "
                            "errors): the data do not look like this arm under this model (torque units? joint "
                            "order? gravity?), so no effect is named")
            log.warning(self.reason_)
            self.joints_ = {}
            return self
        self._check_delay(torque_tests)
        self._check_payload()
        self._check_breakaways(torque_tests)
        if "link_parameters" in tests:
            self._check_links()
        self.onsets_ = {}
        if "backlash" in tests or "stribeck" in tests:
            self._progress(0.7, "onsets")
            for j in sig.joints:
                onset_tests(self, j, tests)
            self._check_net_gain(tests, torque_tests)
            delay_vs_gap(self, torque_tests, tests)      # a delay and a motor-side gap both kept: head to head
        self.effects_found_ = self._ranked_effects()
        self.ambiguous_ = self._ambiguous_groups()
        report_effects(self)
        for j, res in self.joints_.items():
            res.unexplained = unexplained(self, j)
        # an arm-level finding no joint kept (payload or link errors) is said with why, never dropped silently
        self.arm_unnamed_ = arm_unnamed(self)
        self.conclusive_ = True
        # the model written against the declared one on held-out torque, per joint: worse is said, never quiet
        self.against_declared_ = against_declared(self)
        for w in worse_warnings(self.against_declared_):
            log.warning(w)
            self.warnings_.append(w)
        self.positions_ = None
        self.gains_ = None
        self.position_skipped_ = None if self.simulator is not None else "no simulator given"
        if self.simulator is not None:
            self._progress(0.8, "position check")
            self._position_check(data)
        self._progress(1.0, "done")
        return self

    def _signals(self, data) -> Signals:
        """The run's prepared signals, and the declared rigid body (a payload from the model or the run)."""
        meta = data.meta
        payload = self.declared_.payload
        if payload is None and meta.payload is not None and meta.payload.mass_kg > 0:
            payload = Payload(meta.payload.mass_kg, tuple(meta.payload.com_m))
        self.payload_declared_ = payload
        robot = getattr(meta, "robot", None) or "wam7"        # the run's arm: its joints, its datasheet
        self.dynamics_ = WamDynamics(payload, self.declared_.links, robot)
        n = self.dynamics_.n_joints
        kw = {} if self.window_s is None else {"window_s": self.window_s}
        if self.gauss_s is not None:
            kw["gauss_s"] = self.gauss_s
        qd = None
        if all(f"qd_{j}_rad_s" in data.data for j in range(1, n + 1)):
            qd = data.col("qd")[:, :n]
            qd = qd if np.isfinite(qd).all() else None
        q, tau = data.col("q")[:, :n], data.col("tau")[:, :n]
        refused = {}
        if getattr(meta, "torque_kind", "total") == "controller":
            # the controller's output, libbarrett's gravity compensation added downstream and not logged: the
            # declared gravity added back to every joint, exact (a constant) at the joints whose gravity torque is
            # constant over the run, which alone are diagnosed; at the others the declared arm's guess, which only
            # the controller's gains read (the closed-loop check)
            g, refused = constant_gravity(self.dynamics_, q)
            tau = tau + g
        sig = self.signals_ = prepare_signals(data.t_s, q, data.col("q_ref")[:, :n], tau,
                                              float(meta.sample_rate_hz), [j - 1 for j in meta.experiment.joints],
                                              qd_rad_s=qd, **kw)
        # refused: the joints that move (or were commanded to) whose gravity torque varies
        if refuse_joints(sig, refused) and not sig.joints:
            raise DataFormatError(f"{self.source_}: no joint left to diagnose (" + "; ".join(
                f"joint {j + 1}: {why}" for j, why in sig.skipped.items()) + ")")
        return sig

    def _prepare(self, sig: Signals) -> None:
        want_payload = ("payload" in self.candidates and "payload" not in self.declared_effects_) or \
            "link_parameters" in self.candidates
        des, self.jd_ = prepare_design(sig, self.dynamics_, self.declared_.friction, self.declared_.effects,
                                       self.n_blocks, self.n_folds, want_payload)
        shift_rigid_body(des, self.jd_, self.dynamics_, rigid_body_shift_s(self.source_))
        self.design_ = des
        self.decimation_ = des.decimation
        self.union_ = des.union
        self.rnea_full_ = des.rnea_Nm
        self.known_, self.known_other_ = des.known_Nm, des.known_other_Nm

    @property
    def _robot(self) -> str:
        """The run's arm (the declared rigid body's)."""
        return self.dynamics_.robot.name

    def _declared_r2(self) -> float:
        """Share of the moving joints' torque variance the fitted declared model explains (held-out)."""
        ss_res, ss_tot = 0.0, 0.0
        for j, res in self.joints_.items():
            tau = self.jd_[j].extra["tau"]
            ss_res += finite_ss(res.e_base)
            ss_tot += float(np.sum((tau - tau.mean()) ** 2))
        return 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0

    def _rigid_body_r2(self) -> float:
        """The declared model's share of the torque variance once the arm may carry a wrist payload and its links
        may be off by up to twice their declared accuracy (:func:`~wamctl.analysis.diagnosis.links.
        rigid_body_r2`; -inf without the rigid-body regressors)."""
        from wamctl.analysis.diagnosis.links import rigid_body_r2
        from wamctl.analysis.diagnosis.rigid import plausible_link_map

        return rigid_body_r2(self.design_, self.jd_, list(self.joints_),
                             plausible_link_map(self.declared_.links, self.payload_declared_, self._robot),
                             PAYLOAD_COM_BOX_M)

    def _diagnose_joints(self, joints: list[int], tests: list[str]) -> None:
        """:meth:`_diagnose_joint` of every joint of ``joints`` into ``joints_``, side by side in worker processes
        on a long run (:mod:`wamctl.analysis.diagnosis.parallel`): what a joint leaves that later steps read (its
        declared friction, its friction-map test, the statistics and onsets cached on the way) is taken back in
        joint order."""
        workers = self.workers_ = joint_workers(len(joints), self.signals_.n, self.jobs)
        if workers > 1 and "stribeck" in tests:
            friction_map_of(self, joints[0])        # the one cache every joint reads: made once, before the fork
        label = f", {workers} processes" if workers > 1 else ""     # short: the bar keeps 80 columns

        def one(k: int) -> tuple[JointResult, dict, tuple]:
            sig, jd = self.signals_, self.jd_[joints[k]]
            before = cache_keys(sig, jd)
            res = self._diagnose_joint(jd, tests)
            map_test = {jd.j: self.map_tests_[jd.j]} if jd.j in self.map_tests_ else {}
            return res, map_test, caches_since(sig, jd, before)

        finished = []

        def done(k: int) -> None:
            finished.append(k)
            self._progress(0.1 + 0.5 * len(finished) / len(joints),
                           f"torque residual: {len(finished)} of {len(joints)} joints{label}")

        self._progress(0.1, f"torque residual: 0 of {len(joints)} joints{label}")
        for j, (res, map_test, caches) in zip(joints, map_in_order(one, len(joints), workers, done)):
            self.joints_[j] = res
            self.map_tests_.update(map_test)
            adopt_caches(self.signals_, self.jd_[j], caches)

    def _diagnose_joint(self, jd: JointData, tests: list[str], rejected: dict | None = None) -> JointResult:
        """Forward selection of the torque-domain candidates ``tests`` at one joint (``rejected``: candidates
        excluded beforehand, with the reason); Stribeck seen at the breakaways under the declared model is
        offered first (when a joint sticks and slips, few sliding samples remain)."""
        res = joint_baseline(self.design_, jd)
        pre = {}
        if "stribeck" in tests and "stribeck" not in (rejected or {}):
            pre = {"breakaways": stribeck_at_breakaways(self, jd.j), "map": self._map_evidence(jd.j)}
            pre = {k: v for k, v in pre.items() if v is not None}

        def onset_recheck(name: str, other: dict) -> dict | None:
            """Stribeck seen at the breakaways, tested again with a measurement delay in the model (a delay
            leaves the friction map of steady segments and the other candidates leave the breakaway levels as
            they are)."""
            if name != "stribeck" or other["name"] != "delay":
                return None
            if "map" in pre:
                return pre["map"]
            d = float(np.median([h for h in other["h_fold"] if h is not None]))
            return stribeck_at_breakaways(self, jd.j, extra_delay_s=d, test_only=True)

        return forward_select(self.design_, jd, res, tests, self.threshold_, self.max_steps, pre, rejected,
                              onset_recheck)

    def _rediagnose(self, j: int, tests: list[str], name: str, why: str) -> None:
        """0-based joint ``j`` diagnosed again with candidate ``name`` ruled out (``why``), and every candidate an
        earlier arm-wide check ruled out there kept out too (a rejected delay or payload must not come back)."""
        self.rejected_[j][name] = why
        res = self.joints_[j] = self._diagnose_joint(self.jd_[j], tests, dict(self.rejected_[j]))
        res.ambiguous += self.arm_ambiguous_[j]
        pl = getattr(self, "payload_", None)
        if pl is not None and j + 1 in pl["joints_fitted"] and any(t["name"] == "payload" for t in res.kept):
            # the arm's one payload, not a joint's own fit, as :meth:`_check_payload` left it
            terms = global_payload_terms(res.kept, self.n_folds)
            set_after(self.design_, res, self.jd_[j], terms, cv_terms(self.design_, self.jd_[j], terms))

    def _map_evidence(self, j: int) -> dict | None:
        """The friction map's Stribeck test of 0-based joint ``j`` when it passes and is plausible (else None;
        every map test is kept in ``map_tests_``)."""
        if j not in self.map_tests_:
            self.map_tests_[j] = map_evidence(self, j)
        ev = self.map_tests_[j]
        if ev is None or not ev["plausible"] or ev["p_value"] >= self.threshold_ or ev["delta_bic"] >= 0:
            return None
        return ev

    def _check_delay(self, tests: list[str]) -> None:
        """One delay for the arm: joints whose delay disagrees are diagnosed again without it."""
        for j, why in delay_disagreements(self.joints_, self.signals_.dt_s, self.design_,
                                                     self.jd_).items():
            log.info("joint %d: %s", j + 1, why)
            self._rediagnose(j, tests, "delay", why)

    def _check_payload(self) -> None:
        """A payload is one mass for the whole arm, beyond what the arm's own link errors can make: the payload
        fitted over every joint that kept it must win against link errors within the declared accuracy
        (:func:`~wamctl.analysis.diagnosis.links.payload_or_links`; else ``link_parameters`` is tested in its
        place, or the two are ambiguous), be a wrist payload where the data determine it, and be consistent with
        the other joints; else the joints that kept it are diagnosed again without it. Kept, every joint that
        kept it carries the arm's one payload."""
        from wamctl.analysis.diagnosis.links import payload_or_links
        from wamctl.analysis.diagnosis.rigid import plausible_link_map

        self.payload_ = None
        self.payload_vs_links_ = None
        self.links_plausible_ = self.links_skip_ = False
        fit = payload_fit(self.design_, self.joints_, self.jd_)
        if fit is None:
            return
        dec = payload_or_links(self.design_, self.joints_, self.jd_, self.threshold_,
                               plausible_link_map(self.declared_.links, self.payload_declared_, self._robot),
                             PAYLOAD_COM_BOX_M)
        self.payload_vs_links_ = payload_links_summary(dec)
        self.payload_cone_fit_ = None if dec is None else dec["cone_fit"]     # H_P of the next run's design
        why = payload_links_reason(dec)
        ci, ni = {}, []
        if why is None:
            ci, ni = payload_uncertainty(self.design_, self.joints_, self.jd_)
            why = payload_rejection(fit, ni) or payload_inconsistency(self.design_, self.joints_, self.jd_, fit)
        if why is not None:
            self._drop_payload(fit, why, dec)
            return
        self.payload_ = {k: v for k, v in fit.items() if k != "pi"}
        if "mass_kg" in ni and dec is not None and dec["cone_fit"] is not None:
            # the motion does not determine the mass: the model carries a wrist payload that explains the data
            # (reported as not identified)
            self.payload_.update(dec["cone_fit"])
        self.payload_ci_ = (ci, ni)
        # one column per joint (its torque), fitted without each fold for the held-out figures, and on all
        # data for the model
        self.payload_pi_ = self.design_.payload_pi = fold_payloads(self.design_, self.joints_, self.jd_, fit)
        for j in [jj - 1 for jj in fit["joints_fitted"]]:
            res, jd = self.joints_[j], self.jd_[j]
            terms = global_payload_terms(res.kept, self.n_folds)
            set_after(self.design_, res, jd, terms, cv_terms(self.design_, jd, terms))
        if self.payload_vs_links_ and self.payload_vs_links_["grey_zone"]:
            self.warnings_.append(self.payload_vs_links_["grey_zone"])

    def _drop_payload(self, fit: dict, why: str, dec: dict | None) -> None:
        """The joints that kept the payload ``fit`` diagnosed again without it (``why``); an ambiguous
        payload-or-links decision is recorded at them, link errors within the declared accuracy are tested in its
        place when they explain the data as well."""
        log.info(why)
        self.payload_dropped_ = why
        tests = [c for c in self.candidates if c not in self.declared_effects_ and c != "backlash"
                 and c not in ARM_ONLY]
        outcome = dec["outcome"] if dec is not None else None
        for j in [jj - 1 for jj in fit["joints_fitted"]]:
            if outcome == "ambiguous":
                self.arm_ambiguous_[j].append({"names": ["payload", "link_parameters"], "step": "arm",
                                               "evidence": self.payload_vs_links_["tests"]})
            self._rediagnose(j, tests, "payload", why)
        self.links_plausible_ = outcome == "link_parameters" and "link_parameters" in self.candidates
        self.links_skip_ = outcome == "ambiguous"

    def _check_breakaways(self, tests: list[str]) -> None:
        """A Stribeck effect seen only at the breakaways is tested there again under the final model with the
        other effects kept at the joint (a payload, a ripple, a delay change the torque a joint withstood before
        it moved); the joint is diagnosed again without it when the breakaways no longer show it."""
        from wamctl.analysis.diagnosis.onsets import onset_model

        for j, res in list(self.joints_.items()):
            t = next((t for t in res.kept if t["name"] == "stribeck" and t.get("seen") == "at the breakaways"), None)
            if t is None or len(res.kept) < 2:
                continue
            r = stribeck_at_breakaways(self, j, test_only=True, model=onset_model(self, j, exclude=("stribeck",)))
            if r is not None and r["kept"]:
                continue
            why = ("the breakaways show no Stribeck effect once the joint's other effects ("
                   + ", ".join(k["name"] for k in res.kept if k["name"] != "stribeck") + ") are in the model")
            log.info("joint %d: %s", j + 1, why)
            self._rediagnose(j, tests, "stribeck", why)

    def _check_net_gain(self, tests: list[str], torque_tests: list[str]) -> None:
        """A joint's own effect (Stribeck, a ripple, a drift, a dead band behind the encoder) is named only where the
        joint's final model predicts the held-out torque, sliding samples and stalls together, better than the same
        model without it, by at least the minimum effect (``NET_GAIN``). Its evidence was partial: an effect seen at
        the onsets was tested on travel and breakaway ratios, one seen in the torque residual on the sliding samples
        only, while its model also sets the torque a stalled joint withstands. Otherwise the joint is diagnosed
        again without it (and its onsets analysed again). A gap on the motor side has no torque model (the link
        follows the measurement at a constant offset): its evidence is the travel alone. The arm's payload and
        delay are judged over the arm (:meth:`_check_payload`, :meth:`_check_delay`)."""
        own = ("stribeck", "position_ripple", "friction_drift", "backlash")
        for j, res in list(self.joints_.items()):
            seen = [t["name"] for t in res.kept if t["name"] in own and t.get("encoder_side") != "motor"]
            after = res.torque_rms_after_Nm
            weak = []
            for name in seen:
                without = self._rms_without(j, name)
                if not (np.isfinite(after) and np.isfinite(without)) or after <= NET_GAIN * without:
                    continue
                why = (f"the joint's model with it predicts the held-out torque (sliding samples and stalls) no "
                       f"better than without it (RMS {after:.3g} N m against {without:.3g} N m): not an effect the "
                       "torque shows")
                log.info("joint %d: %s: %s", j + 1, name, why)
                self.rejected_[j][name] = why
                weak.append(name)
            if not weak:
                continue
            self._rediagnose(j, torque_tests, weak[0], self.rejected_[j][weak[0]])
            onset_tests(self, j, [c for c in tests if c not in self.rejected_[j]])
            for name in weak:       # the onset tests skipped it: its entry says why
                self.joints_[j].candidates.setdefault(name, {"kept": False})["reason"] = self.rejected_[j][name]

    def _rms_without(self, j: int, name: str) -> float:
        """Held-out torque RMS (sliding samples and stalls) of 0-based joint ``j``'s final model without effect
        ``name``, the other effects refitted."""
        from dataclasses import replace

        from wamctl.analysis.diagnosis.joint import set_rms
        from wamctl.analysis.diagnosis.onsets import joint_onsets, onset_model, stall_residual

        res, jd, des = self.joints_[j], self.jd_[j], self.design_
        without = [t for t in res.kept if t["name"] != name]
        alt = replace(res, candidates=dict(res.candidates))
        set_after(des, alt, jd, without, cv_terms(des, jd, without))
        self.joints_[j] = alt
        try:        # the stalls under that model: its friction levels, its other onset effects' held-out levels
            ons = joint_onsets(des, self.dynamics_, jd, onset_model(self, j))
            ons["fold_coef"] = {k: v for k, v in self.onsets_[j].get("fold_coef", {}).items() if k != name}
            if "use_breakaway" in self.onsets_[j]:
                ons["use_breakaway"] = self.onsets_[j]["use_breakaway"]
            alt.stall_after = stall_residual(self, j, ons, after=True)
        finally:
            self.joints_[j] = res
        set_rms(alt)
        return alt.torque_rms_after_Nm

    def _check_links(self) -> None:
        """``link_parameters`` against the current model (see :mod:`wamctl.analysis.diagnosis.links`): the refit
        within the declared accuracy when a payload candidate was found to be the links' (one joint is enough:
        the payload candidate won that joint's selection), else the free refit (two joints or more); named where
        it adds to the model, beside the arm's payload if one was kept."""
        from wamctl.analysis.diagnosis.crossval import cv_terms
        from wamctl.analysis.diagnosis.links import links_test, links_uncertainty
        from wamctl.analysis.diagnosis.rigid import plausible_link_map

        self.links_test_ = None
        self.links_report_ = None
        if getattr(self, "links_skip_", False):
            return
        plausible = getattr(self, "links_plausible_", False)
        link_map = plausible_link_map(self.declared_.links, self.payload_declared_, self._robot) if plausible else None
        t = links_test(self.design_, self.joints_, self.jd_, self.threshold_, link_map, 1 if plausible else 2)
        self.links_test_ = None if t is None else {k: v for k, v in t.items() if k not in ("e", "e0", "betas")}
        if t is None:
            return
        evidence = {k: t[k] for k in ("p_value", "delta_bic", "F", "n", "n_eff", "ssr_ratio")}
        record = {"vs": "link_parameters", "p_this_beyond": float("nan"), "p_other_beyond": float(t["p_value"])}
        if not t["passes"]:
            for res in self.joints_.values():
                if "payload" in res.candidates and res.candidates["payload"].get("kept"):
                    res.candidates["payload"].setdefault("head_to_head", []).append(dict(record, outcome="wins"))
                res.candidates["link_parameters"] = dict(evidence, kept=False, reason=(
                    "a refit of the arm's link parameters " + ("within their declared accuracy " if plausible else "")
                    + "does not add to the model of the joints " + ("with the payload " if t["has_payload"] else "")
                    + f"(p = {t['p_value']:.3g})"))
            return
        params, ci = links_uncertainty(self.design_, self.joints_, self.jd_, t)
        self.links_report_ = {"params": params, "params_ci": ci,
                              "not_identified": [f"d_{n}" for n in t["not_identified"]],
                              "within_declared_accuracy": bool(plausible)}
        des = self.design_
        des.links_beta, des.links_cols = t["betas"], np.arange(len(t["betas"][None]))
        why = "kept (refit over the arm" + (", within the declared accuracy)" if plausible else ")")
        for j in t["helped"]:
            res, jd = self.joints_[j], self.jd_[j]
            gain = (finite_ss(t["e0"][j]) - finite_ss(t["e"][j])) / max(finite_ss(res.e_base), 1e-300)
            term = {"name": "link_parameters", "h_fold": [("links", f) for f in range(self.n_folds)],
                    "h_all": ("links", None), "fixed_h": ("links", None), "evidence": evidence, "gain": gain,
                    "rms_before_Nm": float(np.sqrt(np.nanmean(t["e0"][j] ** 2))),
                    "rms_after_Nm": float(np.sqrt(np.nanmean(t["e"][j] ** 2)))}
            terms = list(res.kept) + [term]
            set_after(des, res, jd, terms, cv_terms(des, jd, terms))
            res.candidates["link_parameters"] = dict(evidence, kept=True, reason=why)

    def _ranked_effects(self) -> list[str]:
        """Effect names kept anywhere, strongest evidence first: the smallest p-value of each name (p-values
        below 1e-300 tie), then its largest held-out gain."""
        strength = {}
        for res in self.joints_.values():
            for k in res.kept:
                p = max(float(k["evidence"].get("p_value", 1.0)), 1e-300)
                key = (-np.log10(p), k["gain"])
                strength[k["name"]] = max(strength.get(k["name"], key), key)
        return sorted(strength, key=lambda n: strength[n], reverse=True)

    def _ambiguous_groups(self) -> list[tuple[str, ...]]:
        """The ambiguous groups of every joint, each once (names sorted)."""
        groups = []
        for res in self.joints_.values():
            for g in res.ambiguous:
                key = tuple(sorted(g["names"]))
                if key not in groups:
                    groups.append(key)
        return groups

    def _position_check(self, data) -> None:
        """The closed-loop position check, with the controller's gains the log shows (or skipped, said why)."""
        from wamctl.analysis.diagnosis.gains import controller_gains

        if getattr(self.meta_, "reference", None) == "measured":
            self.gains_ = {"kp": None, "kd": None, "source": None, "reason": "no reference logged (the measured "
                           "positions stand in for it): a closed loop has nothing to follow"}
            self.position_skipped_ = self.gains_["reason"]
            log.warning("closed-loop position check skipped: %s", self.position_skipped_)
            return
        mp = self.meta_.payload
        ctl = WamDynamics(Payload(mp.mass_kg, tuple(mp.com_m)) if mp is not None and mp.mass_kg > 0 else None,
                          robot=self.dynamics_.robot)
        self.gains_ = controller_gains(self.signals_, self.meta_, ctl.gravity_many)
        if self.gains_["kp"] is None:
            self.position_skipped_ = self.gains_["reason"]
            log.warning("closed-loop position check skipped: %s", self.position_skipped_)
            return
        meta = self.meta_.model_copy(update={"controller": self.meta_.controller.model_copy(
            update={"kp": self.gains_["kp"], "kd": self.gains_["kd"]})})
        pc = position_check(self, data, self.simulator, self.max_sim_samples or MAX_SIM_SAMPLES, meta)
        self.positions_ = pc
        for j, res in self.joints_.items():
            res.position_rms_before_rad = pc["rms_before"].get(j, float("nan"))
            res.position_rms_after_rad = pc["rms_after"].get(j, float("nan"))
            res.position_not_checked = pc["not_checked"].get(j)

    # ------------------------------------------------------------------------------------------ results
    def effect_params(self, j: int, name: str, theta: np.ndarray | None = None) -> dict:
        """Parameters of kept effect ``name`` at 0-based joint ``j`` (units in the key names); ``theta``
        overrides the coefficients fitted on all data (see :meth:`refit`)."""
        return kept_effect_params(self, j, name, theta)

    def friction_after(self, j: int, theta: np.ndarray | None = None) -> dict:
        """Classic friction of 0-based joint ``j`` in the final model (at t = 0 when friction drifts)."""
        return friction_levels_after(self, j, theta)

    def friction_before(self, j: int, theta: np.ndarray | None = None) -> dict:
        """Classic friction of the declared model (fitted, or the model file's levels plus the fitted
        correction when a model file gives them)."""
        return friction_levels_before(self, j, theta)

    def refit(self, rows_of) -> dict:
        """Coefficients of the declared and the final model of every joint fitted on a subset of samples.

        Parameters
        ----------
        rows_of : callable ``JointData -> (m,) bool``, the samples to fit on (shape parameters are kept).

        Returns
        -------
        {joint: (theta_before, theta_after)}, and under key ``"payload"`` the payload fitted on the subset (None
        when there is none, or when the motion does not determine its mass).
        """
        des = self.design_
        out = {}
        for j, res in self.joints_.items():
            jd = self.jd_[j]
            rows = np.flatnonzero(rows_of(jd))
            if len(rows) < 20:
                out[j] = (res.theta_before, res.theta_after)
                continue
            tb = fit_theta(columns(des, "friction", jd, None)[rows], jd.y_Nm[rows], des.bounded)
            y, X = target_and_design(des, jd, res.kept, None)
            out[j] = (tb, fit_theta(X[rows], y[rows], des.bounded))
        # a payload whose mass the motion does not determine is the model's one (its refit on a subset is not)
        blind = "mass_kg" in getattr(self, "payload_ci_", ({}, []))[1]
        out["payload"] = payload_fit(des, self.joints_, self.jd_, rows_of) \
            if self.payload_ is not None and not blind else None
        return out

    def to_dict(self, data_path: str = "") -> dict:
        """``diagnosis.json`` (format ``wamctl-diagnosis/1``, see docs/diagnosis-report.md)."""
        return diagnosis_dict(self, data_path)

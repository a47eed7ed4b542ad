"""The friction sweep (thesis chapter 4.2): each joint driven at several constant velocities, both directions,
under PD + gravity compensation; the identification then turns the constant-velocity stages into a
friction-velocity map and fitted friction models (:mod:`wamctl.analysis.friction_id`).

Schedule
--------
For every joint of ``sweep.joints`` and every speed of its velocity list (ascending), the joint holds for
``settle_s`` and makes an LSPB move (blend time ``tc_s``) in ``first_direction``, holds again and moves back
at the same speed, so it returns to ``q0``: two directions per speed and the arm ends where it started. A
move travels ``min(travel_rad, v * cruise_s)``: slow moves are short (a few seconds at constant velocity),
fast moves are capped by the travel. The other joints hold ``q0``.

With ``validation`` set, the run continues after the identification with the thesis' rotation test
(section 4.4) twice, under ``pd_g`` and under ``pd_g_ff`` fed by the friction model just identified, so that
the report shows both (tables ``validation_pd_g`` and ``validation_pd_g_ff`` of the run directory).
"""

from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path
from typing import Literal, Union

import numpy as np
from pydantic import Field, field_validator, model_validator

from wamctl.control.trajectory import ReferenceBuilder
from wamctl.experiments.common import Plan, closed_loop_stage, feedforward_for, make_backend, make_controller
from wamctl.model import params as P
from wamctl.specs import Common, Joint, RotationSpec, Strict, check_positions
from wamctl.store import RunDir, json_default

log = logging.getLogger(__name__)

# Default speeds (rad/s), each run in both directions: from below 0.01 rad/s to 1 rad/s, roughly
# logarithmic, so that both the Coulomb level (slow) and the viscous slope (fast) are well determined.
DEFAULT_VELOCITIES_RAD_S = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0]
MODEL_FILE = "friction_model.yaml"
MAP_FILE = "friction_map.csv"
IDENT_FILE = "identification.json"
VALIDATION_TABLES = {"pd_g": "validation_pd_g", "pd_g_ff": "validation_pd_g_ff"}


GRAVITY_BUDGET = 0.6  # largest gravity torque allowed along a sweep, as a fraction of each joint's torque limit


@lru_cache(maxsize=256)
def _travel_problem(q0: tuple, joint: int, travel_rad: float, payload) -> tuple[str, float]:
    """Why moving ``joint`` by ``travel_rad`` from ``q0`` is not allowed ('' if it is), and the largest
    gravity load along the way as a fraction of the torque limit."""
    dyn = _dynamics(payload)
    q = np.tile(np.asarray(q0, float), (9, 1))
    q[:, joint - 1] += np.linspace(0.0, travel_rad, 9)
    try:
        check_positions(q, f"joint {joint} moved by {travel_rad:+.3g} rad from q0_rad")
    except ValueError as exc:
        return str(exc), np.inf
    ratio = np.array([np.abs(dyn.gravity(x)) / P.TAU_MAX_NM for x in q])
    worst = float(ratio.max())
    if worst > GRAVITY_BUDGET:
        i, k = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        return (f"moved by {travel_rad:+.3g} rad, joint {k + 1} would need {ratio[i, k] * P.TAU_MAX_NM[k]:.1f} N m "
                f"against gravity, over {GRAVITY_BUDGET:.0%} of its {P.TAU_MAX_NM[k]:g} N m limit"), worst
    return "", worst


@lru_cache(maxsize=4)
def _dynamics(payload):
    from wamctl.model.dynamics import Payload, WamDynamics
    return WamDynamics(Payload(payload[0], payload[1]) if payload else None)


class SweepSection(Strict):
    """What the sweep does: joints, speeds (magnitudes; each run both ways), travel and timing."""

    joints: list[Joint] = Field(default_factory=lambda: list(range(1, P.N_JOINTS + 1)))
    velocities_rad_s: Union[list[float], dict[Joint, list[float]]] = Field(
        default_factory=lambda: list(DEFAULT_VELOCITIES_RAD_S),
        description="speed magnitudes, shared or per joint ({joint: [...]}); each is run in both directions")
    travel_rad: Union[float, dict[Joint, float]] = Field(
        0.6, description="largest travel of one move (shared or per joint); slow moves travel v * cruise_s + "
                         "lag_margin_rad")
    cruise_s: float = Field(2.0, gt=0.0, le=60.0, description="target length of the constant-velocity stage")
    lag_margin_rad: Union[Literal["auto"], float, dict[Joint, float]] = Field(
        "auto", description="extra travel of slow moves, eaten while the PD error builds up to the breakaway "
                            "torque (the joint sticks meanwhile); auto: 2 * prior Coulomb level / kp")
    min_cruise_s: float = Field(0.4, gt=0.0, description="shortest constant-velocity stage accepted")
    tc_s: float = Field(0.25, gt=0.0, le=2.0, description="LSPB blend (acceleration) time")
    settle_s: float = Field(0.4, ge=0.0, le=10.0, description="hold before each move")
    first_direction: Union[Literal["auto", "positive", "negative"],
                           dict[Joint, Literal["auto", "positive", "negative"]]] = Field(
        "auto", description="direction of the first move of each pair (shared or per joint); auto: the side "
                            "within the joint limits with the smaller gravity load")

    @field_validator("joints")
    @classmethod
    def _unique_joints(cls, v):
        if not v:
            raise ValueError("at least one joint")
        if len(set(v)) != len(v):
            raise ValueError(f"joints repeated: {v}")
        return v

    @field_validator("velocities_rad_s")
    @classmethod
    def _speeds(cls, v):
        lists = v.values() if isinstance(v, dict) else [v]
        for speeds in lists:
            if len(speeds) < 2:
                raise ValueError("at least two speeds per joint (a line needs two points per direction)")
            bad = [s for s in speeds if not s > 0]
            if bad:
                raise ValueError(f"speeds are magnitudes (> 0), each run in both directions; got {bad}")
            if len(set(speeds)) != len(speeds):
                raise ValueError(f"speeds repeated: {speeds}")
        return v

    @field_validator("travel_rad")
    @classmethod
    def _travel(cls, v):
        vals = v.values() if isinstance(v, dict) else [v]
        if any(not x > 0 for x in vals):
            raise ValueError("travel must be > 0 rad")
        return v

    # --- per joint accessors (1-based joint numbers) ----------------------------------------------
    def speeds(self, joint: int) -> list[float]:
        v = self.velocities_rad_s
        return sorted(v[joint] if isinstance(v, dict) else v)

    def travel(self, joint: int) -> float:
        t = self.travel_rad
        return float(t.get(joint, 0.6)) if isinstance(t, dict) else float(t)

    def direction_setting(self, joint: int) -> str:
        d = self.first_direction
        return d.get(joint, "auto") if isinstance(d, dict) else d

    def lag_margin(self, joint: int, kp: np.ndarray) -> float:
        """Extra travel of a slow move of ``joint`` (rad); ``kp`` (7,) are the sweep's proportional gains."""
        m = self.lag_margin_rad
        if m == "auto":
            # Under PD a joint at rest starts to slide once kp * e exceeds the breakaway torque, and after a
            # reversal it first unwinds the residual error of the previous move: about 2 Fc / kp of the
            # reference passes while it sticks. Prior Fc: the larger Table 4.1 level of the joint.
            prior = max(P.TABLE_4_1_FC_POS_NM[joint - 1], P.TABLE_4_1_FC_NEG_NM[joint - 1])
            return float(np.clip(2.0 * prior / kp[joint - 1], 0.001, 0.05))
        return float(m.get(joint, 0.0)) if isinstance(m, dict) else float(m)

    def move_travel(self, joint: int, speed: float, kp: np.ndarray) -> float:
        """Travel of one move at ``speed``: ``min(travel, speed * cruise_s + lag margin)``."""
        return min(self.travel(joint), speed * self.cruise_s + self.lag_margin(joint, kp))


class ValidationSection(Strict):
    """Rotation test (thesis 4.4) after the identification, under pd_g and under pd_g_ff with the new model."""

    joints: list[Joint] = Field(default_factory=lambda: list(range(1, P.N_JOINTS + 1)))
    amplitude_rad: float = P.ROTATION_AMPLITUDE_RAD
    velocity_rad_s: float = Field(P.ROTATION_VELOCITY_RAD_S, gt=0.0, le=2.0)
    tc_s: float = Field(P.LSPB_TC_S, gt=0.0)
    settle_s: float = Field(0.3, ge=0.0)
    hold_s: float = Field(1.0, ge=0.0)

    @field_validator("amplitude_rad")
    @classmethod
    def _nonzero(cls, v):
        if v == 0:
            raise ValueError("the rotation must not be zero")
        return v


class IdentificationSection(Strict):
    """Options of the identification (analysis) step."""

    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = Field(
        "linear", description="least-squares loss; soft_l1/huber/cauchy down-weight outlying segments")
    criterion: Literal["bic", "aic"] = "bic"
    weighting: Literal["se", "none"] = Field(
        "se", description="se: weight segments by their standard error (plus a model-error term); none: the "
                          "thesis' unweighted least squares (eq. 4.2)")
    folds: int = Field(5, ge=2, le=20, description="k-fold over segments for the held-out criterion")
    models: list[Literal["classic", "classic_symmetric", "stribeck"]] = \
        Field(default_factory=lambda: ["classic", "classic_symmetric", "stribeck"], min_length=1)


class FrictionSweepSpec(Common):
    kind: Literal["friction_sweep"]
    sweep: SweepSection = SweepSection()
    identification: IdentificationSection = IdentificationSection()
    validation: ValidationSection | None = None

    @model_validator(mode="after")
    def _check_sweep(self):
        s = self.sweep
        q0 = np.array(self.q0_rad)
        kp = self.controller.gains()[0]
        if not isinstance(s.lag_margin_rad, str):
            vals = s.lag_margin_rad.values() if isinstance(s.lag_margin_rad, dict) else [s.lag_margin_rad]
            if any(not 0 <= x <= 0.5 for x in vals):
                raise ValueError("sweep.lag_margin_rad: between 0 and 0.5 rad")
        if isinstance(s.velocities_rad_s, dict):
            missing = [j for j in s.joints if j not in s.velocities_rad_s]
            if missing:
                raise ValueError(f"sweep.velocities_rad_s: no speeds for joint(s) {missing}")
        if 2 * s.tc_s > 60:
            raise ValueError("sweep.tc_s: too long")
        for j in s.joints:
            for v in s.speeds(j):
                if v > P.QD_MAX_RAD_S[j - 1]:
                    raise ValueError(f"sweep.velocities_rad_s: joint {j} speed {v} rad/s above the limit "
                                     f"{P.QD_MAX_RAD_S[j - 1]} rad/s")
                cruise = s.move_travel(j, v, kp) / v
                if cruise < s.min_cruise_s:
                    raise ValueError(f"sweep.travel_rad: joint {j} at {v} rad/s travels {s.move_travel(j, v, kp):.3g} "
                                     f"rad, only {cruise:.2f} s at constant velocity (min_cruise_s "
                                     f"{s.min_cruise_s} s); raise travel_rad or drop the speed")
            self.first_sign(j)  # raises naming the field when neither allowed direction fits
        if self.validation is not None:
            for j in self.validation.joints:
                q = q0.copy()
                q[j - 1] += self.validation.amplitude_rad
                check_positions(q, "validation.amplitude_rad")
        return self

    def _payload(self):
        p = self.plant.effects.payload or self.controller.declared_payload
        return (p.mass_kg, tuple(p.com_m)) if p else None

    def first_sign(self, joint: int) -> float:
        """+1 or -1: direction of the first move of each pair of ``joint`` (resolves ``auto``).

        A direction is allowed when the whole travel stays within the joint limits and the gravity torque of
        every joint stays within :data:`GRAVITY_BUDGET` of its torque limit (the rest is for the PD, friction
        and acceleration; beyond it the arm sags on the torque limit and the sweep is spoilt).
        """
        s = self.sweep
        setting = s.direction_setting(joint)
        options = {"positive": [1.0], "negative": [-1.0], "auto": [1.0, -1.0]}[setting]
        problems, best = [], None
        for sign in options:
            why, load = _travel_problem(tuple(self.q0_rad), joint, sign * s.travel(joint), self._payload())
            if why:
                problems.append(why)
            elif best is None or load < best[1] - 1e-9:
                best = (sign, load)
        if best is None:
            raise ValueError(f"sweep.travel_rad: joint {joint}: {'; '.join(problems)}; shorten sweep.travel_rad"
                             + (" or set sweep.first_direction" if setting != "auto" else "") + " or change q0_rad")
        return best[0]


# ------------------------------------------------------------------------------------------------ plan
def build_reference(spec: FrictionSweepSpec):
    """The whole sweep as one Reference, and the list of moves ``(index, joint, velocity_rad_s, travel_rad)``
    (signed velocity and travel), in order."""
    s = spec.sweep
    kp = spec.controller.gains()[0]
    b = ReferenceBuilder(spec.q0_rad, 1.0 / P.CONTROL_RATE_HZ)
    moves = []
    for j in s.joints:
        sign = spec.first_sign(j)
        for v in s.speeds(j):
            d = s.move_travel(j, v, kp)
            for direction in (sign, -sign):
                b.hold(s.settle_s, f"settle joint {j}")
                b.move({j - 1: direction * d}, v, s.tc_s, f"joint {j} v={direction * v:+.4g} rad/s")
                moves.append((j, direction * v, direction * d))
    ref = b.hold(s.settle_s, "final hold").build()
    starts = [i for i, label in ref.segments if label.startswith("joint ")]
    return ref, [(i, *m) for i, m in zip(starts, moves)]


def plan(spec: FrictionSweepSpec, base_dir: Path | None = None) -> Plan:
    ref, moves = build_reference(spec)
    s = spec.sweep
    kp = spec.controller.gains()[0]
    arm_s = len(ref) / P.CONTROL_RATE_HZ
    summary = [f"friction sweep: joints {s.joints}, {len(moves)} moves "
               f"({len(moves) // max(1, len(s.joints))} per joint: each speed out and back)",
               f"controller {spec.controller.kind}, backend {spec.backend.kind}, "
               f"plant effects: {', '.join(spec.plant.effects.names()) or 'none'}",
               f"blend {s.tc_s} s, settle {s.settle_s} s, travel <= {s.travel_rad} rad, cruise <= {s.cruise_s} s",
               f"{len(ref)} ticks at {P.CONTROL_RATE_HZ:.0f} Hz = {arm_s:.1f} s of arm time"]
    for j in s.joints:
        summary.append(f"  joint {j}: first {'+' if spec.first_sign(j) > 0 else '-'}, speeds {s.speeds(j)} rad/s, "
                       "travel " + ", ".join(f"{s.move_travel(j, v, kp):.3g}" for v in s.speeds(j)) + " rad")
    if spec.validation is not None:
        val = validation_specs(spec, None)
        extra = sum(len(_rotation_plan(v).reference) for v in val.values()) / P.CONTROL_RATE_HZ
        summary.append(f"then the rotation test under pd_g and pd_g_ff (identified model): {extra:.1f} s more")
    return Plan(ref, summary, feedforward_for(spec, ref, base_dir))


# ------------------------------------------------------------------------------------------------ execute
def execute(spec: FrictionSweepSpec, plan: Plan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    """Run the sweep, identify, write ``friction_model.yaml`` (and the map), then the optional validation."""
    from wamctl.analysis.friction_id import identify
    from wamctl.measured import load_run_data

    ref = plan.reference
    for i, label in ref.segments:
        if not label.startswith("joint "):
            run.event(ref.t_s[i], "segment", None, label)
    for i, j, v, d in build_reference(spec)[1]:
        run.event(ref.t_s[i], "move", j, f"velocity_rad_s={v:.6g} travel_rad={d:.6g}")
    run.flush_events()
    n_total = len(ref)
    val_specs = validation_specs(spec, run.path) if spec.validation is not None else {}
    # the references do not depend on the controller: size the progress bar before the model file exists
    n_val = sum(len(_rotation_plan(v).reference) for v in validation_specs(spec, None).values()) \
        if val_specs else 0

    def sub_progress(offset, label):
        if progress is None:
            return None
        return lambda done, total, _l=None: progress(offset + done, n_total + n_val, label)

    with make_backend(spec, base_dir) as backend:
        run.update_manifest(backend=backend.describe())
        closed_loop_stage(backend, make_controller(spec, plan.feedforward_Nm), ref, run,
                          sub_progress(0, "friction sweep"))
    result = identify(load_run_data(run.path), spec.identification.model_dump())
    write_identification(run.path, result)
    offset = n_total
    for kind, rspec in val_specs.items():
        rp = _rotation_plan(rspec, base_dir)
        with make_backend(rspec, base_dir, seed=spec.seed + 1) as backend:
            closed_loop_stage(backend, make_controller(rspec, rp.feedforward_Nm), rp.reference, run,
                              sub_progress(offset, f"rotation test {kind}"), table=VALIDATION_TABLES[kind])
        offset += len(rp.reference)


def write_identification(path: Path, result) -> None:
    """``friction_model.yaml``, ``friction_map.csv`` and ``identification.json`` into ``path``."""
    import json
    path = Path(path)
    result.model.save(path / MODEL_FILE, extra=result.file_extra())
    result.map.to_csv(path / MAP_FILE, index=False)
    (path / IDENT_FILE).write_text(json.dumps(result.to_dict(), indent=2, default=json_default))


def validation_specs(spec: FrictionSweepSpec, run_path: Path | None) -> dict[str, RotationSpec]:
    """The two rotation specs of the validation: pd_g, and pd_g_ff fed by the run's ``friction_model.yaml``."""
    v = spec.validation
    common = spec.model_dump(include={"name", "seed", "backend", "plant", "q0_rad", "out_dir"})
    ctl = spec.controller.model_dump()
    rot = {"joints": v.joints, "mode": "one_at_a_time", "amplitude_rad": v.amplitude_rad,
           "velocity_rad_s": v.velocity_rad_s, "tc_s": v.tc_s, "settle_s": v.settle_s, "hold_s": v.hold_s}
    ff_file = str(Path(run_path) / MODEL_FILE) if run_path is not None else "table_4_1"
    out = {}
    for kind in ("pd_g", "pd_g_ff"):
        c = dict(ctl, kind=kind, ki=None, friction_ff=ff_file if kind == "pd_g_ff" else None)
        out[kind] = RotationSpec.model_validate(dict(common, kind="rotation", controller=c, rotation=rot))
    return out


def _rotation_plan(rspec: RotationSpec, base_dir: Path | None = None) -> Plan:
    from wamctl.experiments import rotation
    return rotation.plan(rspec, base_dir)


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None):
    from wamctl.report.friction import friction_report
    return friction_report(run_path, manifest, spec, out_dir)


# ------------------------------------------------------------------------------------------------ recorded data
def analyse_recorded(source: Path, out: Path | None = None, runs_dir: Path = Path("runs"),
                     name: str | None = None, options: dict | None = None):
    """Identify friction from a recorded sweep (a measured-run directory or a run directory).

    Without ``out`` a new run directory of kind ``friction_sweep`` is created under ``runs_dir`` holding the
    samples (so that ``wamctl report`` takes it again), the friction model and the report; with ``out`` the
    friction model, map and report are written into ``out`` and nothing else is created.

    Returns
    -------
    (directory written, FrictionIdentification, Document)
    """
    from wamctl.analysis.friction_id import identify
    from wamctl.measured import load_run_data
    from wamctl.report.friction import friction_document
    from wamctl.store import open_run

    source = Path(source)
    rd = load_run_data(source)   # DataFormatError naming the file, key, column or row
    ident = identify(rd, options)
    src_spec: dict = {}
    src_backend = "measured"
    if (source / "manifest.json").is_file():
        manifest, src_spec = open_run(source)
        src_backend = (manifest.get("backend") or {}).get("name", "measured")
        name = name or manifest.get("name")
    if out is None:
        meta = rd.meta.model_dump(mode="json")
        spec = {"kind": "friction_sweep", "name": name or source.name, "q0_rad": meta.get("q0"),
                "controller": {"kind": rd.meta.controller.kind, "kp": rd.meta.controller.kp,
                               "kd": rd.meta.controller.kd, "gravity_compensation": rd.meta.gravity_compensation},
                "identification": dict(options or {}), "measured_meta": meta}
        if rd.truth is not None:
            spec["plant"] = rd.truth   # keeps the simulated truth for the report
        run = RunDir.create(runs_dir, spec["name"], spec, None, "friction_sweep",
                            {"backend": {"name": "sim" if rd.truth is not None else src_backend},
                             "analysed_from": str(source.resolve())})
        run.write_table("data", rd.data)
        run.finish("completed", None)
        target = run.path
    else:
        target = Path(out)
        target.mkdir(parents=True, exist_ok=True)
    write_identification(target, ident)
    header = f"Recorded sweep {source} ({'run directory' if src_spec else 'measured run'})."
    doc = friction_document(rd, ident, target, f"Friction identification: {name or source.name}", header)
    doc.write(target, "report")
    return target, ident, doc

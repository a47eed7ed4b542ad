"""The plan of a block: the start pose and every spot solved palm down (reachable, in view, holdable against
gravity), the trials in order, and the seed of each trial's virtual subject."""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wamctl.control.trajectory import Reference
from wamctl.errors import SpecError
from wamctl.experiments.common import Plan
from wamctl.hmi.kinematics import PALM_DOWN_YAW_RAD, HandKinematics, palm_down_rotation
from wamctl.hmi.scene import CommandMapping, SceneCamera, Workspace
from wamctl.hmi.strategy import PROFILES
from wamctl.io import resolve_path
from wamctl.model import params as P
from wamctl.specs import check_positions
from wamctl.specs.hmi_block import HmiBlockSpec, HmiTask

#: Largest gravity torque, as a fraction of the torque limit, at the start and the spots / at the workspace corners.
GRAVITY_BUDGET_SPOTS = 0.85
GRAVITY_BUDGET_CORNERS = 0.95


@dataclass(frozen=True)
class Trial:
    number: int  # 1-based, block order
    location: str
    attempt: int
    xy_m: tuple[float, float]


@dataclass
class HmiPlan(Plan):
    """The plan plus what the block needs: poses, geometry, trials."""

    q_start: np.ndarray = field(default_factory=lambda: np.zeros(P.N_JOINTS))
    q_home: np.ndarray = field(default_factory=lambda: np.zeros(P.N_JOINTS))
    q_targets: dict[str, np.ndarray] = field(default_factory=dict)
    R_ref: np.ndarray = field(default_factory=lambda: np.eye(3))
    camera: SceneCamera | None = None
    mapping: CommandMapping | None = None
    workspace: Workspace | None = None
    trials: list[Trial] = field(default_factory=list)
    condition: str = ""


def make_trials(task: HmiTask, seed: int) -> list[Trial]:
    """The block's trials in order (``order``: by location, interleaved, or shuffled with ``seed``)."""
    locs = task.locations or list(task.targets_m)
    if task.order == "interleaved":
        pairs = [(loc, a) for a in range(1, task.attempts + 1) for loc in locs]
    else:
        pairs = [(loc, a) for loc in locs for a in range(1, task.attempts + 1)]
    if task.order == "shuffled":
        perm = np.random.default_rng(np.random.SeedSequence([seed, 77])).permutation(len(pairs))
        shuffled = [pairs[i][0] for i in perm]
        seen: dict[str, int] = {}
        pairs = []
        for loc in shuffled:
            seen[loc] = seen.get(loc, 0) + 1
            pairs.append((loc, seen[loc]))
    return [Trial(i + 1, loc, a, (float(task.targets_m[loc][0]), float(task.targets_m[loc][1])))
            for i, (loc, a) in enumerate(pairs)]


def trial_seed(subject_seed: int, condition: str, number: int) -> int:
    """Seed of the virtual subject in one trial: from the subject's seed, the condition label and the trial
    number (so a resumed block repeats the same trials, and each condition's session differs)."""
    return int(np.random.SeedSequence([subject_seed, zlib.crc32(condition.encode()), number]).generate_state(1)[0])


def make_camera(task: HmiTask) -> SceneCamera:
    eye = task.camera.eye_m
    look = task.camera.look_at_m or task.start_m
    return SceneCamera((eye[0], eye[1], task.table_z_m + eye[2]), (look[0], look[1], task.z_tool_m),
                         task.camera.focal_px)


def _check_gravity(spec: HmiBlockSpec, kin: HandKinematics, R_ref: np.ndarray, q_start: np.ndarray,
                   q_targets: dict[str, np.ndarray]) -> None:
    """SpecError when the arm could not hold the hand at a spot or a workspace corner (joint torque limits)."""
    from wamctl.model.dynamics import Payload, WamDynamics
    h = spec.hmi
    load = spec.plant.effects.payload or spec.controller.declared_payload
    dyn = WamDynamics(Payload(load.mass_kg, tuple(load.com_m)) if load else None)
    checks = [("hmi.start_m", q_start, GRAVITY_BUDGET_SPOTS)]
    checks += [(f"hmi.targets_m.{k}", q, GRAVITY_BUDGET_SPOTS) for k, q in q_targets.items()]
    for x in h.workspace.x_m:
        for y in h.workspace.y_m:
            q, ep, _ = kin.solve((x, y, h.z_tool_m), R_ref, q_start)
            if ep > 1e-3:
                raise SpecError(f"hmi.workspace: corner ({x}, {y}) m cannot be reached palm down at "
                                f"{h.z_tool_m:.3f} m")
            checks.append((f"hmi.workspace corner ({x}, {y}) m", q, GRAVITY_BUDGET_CORNERS))
    for where, q, budget in checks:
        ratio = np.abs(dyn.gravity(q)) / P.TAU_MAX_NM
        j = int(np.argmax(ratio))
        if ratio[j] > budget:
            raise SpecError(f"{where}: holding the hand there takes {ratio[j] * P.TAU_MAX_NM[j]:.1f} N m on joint "
                            f"{j + 1} against gravity, over {budget:.0%} of its {P.TAU_MAX_NM[j]:g} N m limit; "
                            f"bring it closer to the arm or raise hmi.table_z_m")


def _solve_start(h: HmiTask, kin: HandKinematics, R_ref: np.ndarray) -> np.ndarray:
    """The start pose: palm down over the start cross at the grasp height; SpecError if out of reach."""
    z = h.z_tool_m
    q_start, ep, eo = kin.solve((h.start_m[0], h.start_m[1], z), R_ref, h.start_q_rad)
    if ep > 1e-3 or eo > 1e-2:
        raise SpecError(f"hmi.start_m: ({h.start_m[0]}, {h.start_m[1]}) m at {z:.3f} m cannot be reached palm down "
                        f"(residual {ep * 1e3:.1f} mm, {math.degrees(eo):.1f} deg)")
    return q_start


def _solve_spots(h: HmiTask, kin: HandKinematics, R_ref: np.ndarray, q_start: np.ndarray,
                 camera: SceneCamera) -> dict[str, np.ndarray]:
    """Each spot's pose, palm down at the grasp height; SpecError if one cannot be reached or is outside the
    subject's view."""
    z = h.z_tool_m
    q_targets = {}
    for loc in h.locations or list(h.targets_m):
        x, y = h.targets_m[loc]
        q, ep, eo = kin.solve((x, y, z), R_ref, q_start)
        if ep > 1e-3 or eo > 1e-2:
            raise SpecError(f"hmi.targets_m.{loc}: ({x}, {y}) m cannot be reached palm down at {z:.3f} m "
                            f"(residual {ep * 1e3:.1f} mm, {math.degrees(eo):.1f} deg)")
        if not camera.in_image((x, y, z)):
            raise SpecError(f"hmi.targets_m.{loc}: ({x}, {y}) m is outside the subject's scene image; move the spot "
                            f"or hmi.camera")
        q_targets[loc] = q
    return q_targets


def plan(spec: HmiBlockSpec, base_dir: Path | None = None) -> HmiPlan:
    """Check that a replayed file exists; solve the start pose and every spot palm down (reachability), check
    the view; list the trials."""
    h = spec.hmi
    _check_replay_file(h, base_dir)
    kin = HandKinematics(tool_offset_m=h.tool_offset_m)
    R_ref = palm_down_rotation(PALM_DOWN_YAW_RAD)
    q_start = _solve_start(h, kin, R_ref)
    camera = make_camera(h)
    q_targets = _solve_spots(h, kin, R_ref, q_start, camera)
    _check_gravity(spec, kin, R_ref, q_start, q_targets)
    q_home = np.asarray(h.home_q_rad, float) if h.home_q_rad is not None else q_start.copy()
    try:
        check_positions(q_home, "hmi.home_q_rad")
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    trials = make_trials(h, h.subject.seed)
    rows = [np.asarray(spec.q0_rad, float), q_start, *q_targets.values(), q_home]
    labels = ["q0", "start"] + [f"spot {k}" for k in q_targets] + ["home"]
    q = np.array(rows)
    ref = Reference(np.arange(len(q)) / P.CONTROL_RATE_HZ, q, np.zeros_like(q), np.zeros_like(q),
                    [(i, lab) for i, lab in enumerate(labels)])
    mapping = camera.mapping()
    return HmiPlan(ref, _summary(h, trials, mapping, q_start), None, q_start=q_start, q_home=q_home,
                   q_targets=q_targets, R_ref=R_ref, camera=camera, mapping=mapping,
                   workspace=Workspace(tuple(h.workspace.x_m), tuple(h.workspace.y_m)), trials=trials,
                   condition=h.condition_label())


def _check_replay_file(h: HmiTask, base_dir: Path | None) -> None:
    """A replayed gaze file or capture must exist before anything runs (a spec copied with its placeholder
    path otherwise fails only once the run has started)."""
    if h.source.kind not in ("replay", "replay-raw"):
        return
    path = resolve_path(h.source.path, base_dir)
    if not path.is_file():
        where = "from the working directory" + (f" or from the spec's folder {base_dir}" if base_dir else "")
        raise SpecError(f"hmi.source.path: no file {h.source.path} ({where})")


def _signed(x: float) -> str:
    """``+0.50`` / ``-1.00`` / ``0.00`` (no negative zero)."""
    r = round(float(x), 2)
    return f"{r:+.2f}" if r else "0.00"


def _summary(h: HmiTask, trials: list[Trial], mapping: CommandMapping, q_start: np.ndarray) -> list[str]:
    locs = h.locations or list(h.targets_m)
    z = h.z_tool_m
    f = h.resolved_filter()
    profile = PROFILES[h.profile.kind](h.profile.speed())
    dist = {loc: math.dist(h.targets_m[loc], h.start_m) for loc in locs}
    summary = [
        f"hmi block: subject {h.subject.id} ({h.source.kind} source"
        + (f", seed {h.subject.seed}, skill {h.subject.skill}, fatigue {h.subject.fatigue_per_min}/min"
           if h.source.kind == "virtual" else "") + ")",
        f"condition {h.condition_label()}: {h.strategy} control, filter {f.label()}, {profile.name} profile "
        f"({', '.join(f'{v:.3f}' for v in profile.speeds_m_s)} m/s)",
        f"{len(trials)} trials ({len(locs)} spots x {h.attempts} attempt{'s' if h.attempts != 1 else ''}, "
        f"{h.order}), time-out {h.timeout_s:g} s, "
        f"hit radius {h.hit_radius_m * 1e3:.0f} mm, supervisor start: {h.start_mode()}",
        f"start cross ({h.start_m[0]:.3f}, {h.start_m[1]:.3f}) m, grasp centre at z0 = {z:.3f} m "
        f"({h.grasp_height_m:.3f} m above the table), workspace x {h.workspace.x_m}, y {h.workspace.y_m} m",
        f"image right -> table ({_signed(mapping.right_xy[0])}, {_signed(mapping.right_xy[1])}), image up -> table "
        f"({_signed(mapping.forward_xy[0])}, {_signed(mapping.forward_xy[1])})",
        f"start pose q = [{', '.join(f'{v:.3f}' for v in q_start)}] rad",
    ]
    summary += [f"  {loc}: ({h.targets_m[loc][0]:.3f}, {h.targets_m[loc][1]:.3f}) m, {dist[loc]:.3f} m from the "
                f"start, reachable palm down" for loc in locs]
    return summary

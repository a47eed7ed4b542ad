"""wamctl's import and estimators on public recordings of real WAMs (docs/real-data.md).

The recordings are not in the repository (see docs/real-data.md for where each comes from and how its excerpt
is cut); give the folder that holds them, one sub-folder per recording as named in tests/fixtures/real/:

    python benchmarks/real_data.py --data DIR [--out DIR] [--holdout 0.25]

For each recording it runs, as a user would, ``wamctl import`` and then ``wamctl identify``, ``wamctl
friction-id --data`` and ``wamctl diagnose`` on the imported run, and prints each command's exit code and first
line of error or its held-out figures. Beside them, the reference every estimator must beat: the datasheet arm
(wamctl's rigid-body model, armature included) plus per-joint Coulomb + viscous friction and a constant offset
fitted by least squares on the first part of the run, evaluated on the last ``--holdout`` part (identify's own
default split is the last quarter). Accelerations: Savitzky-Golay second derivative of the logged positions
(cubic, 0.1 s window); velocities: the logged ones (their first derivative where the log has none). Reported
per moving joint (range above 0.1 rad): the held-out torque RMS, and over the moving joints the relative error
||tau - tau_hat|| / ||tau|| (the figure of Sousa and Cortesao's identification of a real 7-DOF WAM: 6.7-8.5 % held out).

The datasheet reference needs the whole arm's torque: it is computed only where the log's torque is ``total``
(libbarrett's jtSum, wam_node's effort), with the datasheet arm of the robot the recording names (wam7, wam4).
Logs without a reference (JointState records, a recorder's table; the analyses let the measured positions stand
in for it) are also split in a training and a held-out part, each imported in the recording's own format, and
every model fitted on the first is checked on the second.
Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

ROOT = Path(__file__).resolve().parents[1]
WAMCTL = str(Path(sys.executable).with_name("wamctl"))
MOVING_RANGE_RAD = 0.1      # a joint whose logged position spans less than this is held, not moving
SAVGOL_WINDOW_S = 0.1


@dataclass(frozen=True)
class Recording:
    name: str               # the sub-folder (and tests/fixtures/real/<name>/PROVENANCE.md)
    file: str               # the file inside it
    robot: str              # wam7 | wam4
    torque: str             # total | controller | measured
    import_args: tuple[str, ...]
    # a wam7 whose wrist was held and not logged (a "4-DOF" log of a 7-DOF arm): its joints 5-7 (rad), to compare
    # the wam4 datasheet (no wrist) with the wam7's (wrist held there)
    held_wrist_rad: tuple[float, float, float] | None = None


RECORDINGS = (
    Recording("alberta-wam7-j2j4-fourier", "state_4.json", "wam7", "total",
              ("--format", "jointstate-json")),
    Recording("cvrg-wam4-ctc-regulation", "run2.csv", "wam4", "total",
              ("--format", "libbarrett-csv", "--rate-hz", "500",
               "--layout", "t,q_ref[4],qd_ref[4],qdd_ref[4],q[4],qd[4],skip[4],tau[4]")),
    Recording("cvrg-wam4-ctc-regulation", "run2.csv", "wam4", "controller",
              ("--format", "libbarrett-csv", "--rate-hz", "500",
               "--layout", "t,q_ref[4],qd_ref[4],qdd_ref[4],q[4],qd[4],tau[4],skip[4]")),
    Recording("iitk-wam4-hosmc-j1-sine", "disturbancesHOSMC1_1.csv", "wam4", "controller",
              ("--format", "libbarrett-csv", "--rate-hz", "500",
               "--layout", "t,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]")),
    Recording("alberta-zeus-4dof-fourier", "rbtlog_15_zeus_4dof_excerpt.dat", "wam4", "total",
              ("--format", "table", "--layout", "t,q[4],tau[4]"),
              held_wrist_rad=(0.0212, -0.1193, 0.0356)),
    # a second arm of the same lab ("slax"), the same recorder; its wrist commanded to zero and held within 0.06 rad
    Recording("alberta-slax-4dof-fourier", "rbtlog_11_slax_4dof_excerpt.dat", "wam4", "total",
              ("--format", "table", "--layout", "t,q[4],tau[4]"),
              held_wrist_rad=(0.0244, -0.0513, 0.0059)),
)


def run(args: list[str]) -> tuple[int, str]:
    """Run a wamctl command; its exit code and what it printed: with --json, stdout alone when it is the JSON
    answer (exit 0, and exit 3, identify's "held-out check failed, model not written"), else stdout and stderr."""
    done = subprocess.run([WAMCTL, *args], capture_output=True, text=True, cwd=ROOT)
    if "--json" in args and json_answer(done.stdout) is not None:
        return done.returncode, done.stdout.strip()
    return done.returncode, (done.stdout + done.stderr).strip()


def json_answer(text: str) -> dict | None:
    """The JSON object a command printed with --json, or None when it printed none (an error)."""
    start = text.find("{")
    if start < 0:
        return None
    try:
        out = json.loads(text[start:])
    except json.JSONDecodeError:
        return None
    return out if isinstance(out, dict) else None


def first_error(text: str) -> str:
    for line in text.splitlines():
        if line.lower().startswith("error"):
            return line
    return text.splitlines()[-1] if text else ""


def summary_line(command: str, code: int, text: str) -> str:
    """What a command's --json output says in one line: identify's held-out check, diagnose's effects, or the
    first error."""
    out = json_answer(text) if code == 0 or command == "identify" else None
    if out is None:
        return first_error(text)
    if command == "identify":
        check = out["held_out_check"]
        band = identify_band(out.get("run_dir"))
        if check.get("model_written", True):
            return check["statement"] + band
        return f"{check['statement']} [model.yaml not written; kept as {check['model_file']}]{band}"
    if command == "diagnose":
        return f"effects found: {out['effects_found']}"
    return f"run directory {out.get('run_dir')}"


def identify_band(run_dir: str | None) -> str:
    """The band identify fitted and judged in (its identification.json: the fitting runs' second filter and the
    held-out rows'), as " [second filter: fit 0.08 s, check 0.08 s]" (none: the diagnosis' band alone)."""
    path = Path(run_dir or "") / "identification.json"
    if not run_dir or not path.exists():
        return ""
    res = json.loads(path.read_text())

    def say(ws):
        return ", ".join("none" if w is None else f"{w:g} s" for w in ws) or "?"

    fit = say(f.get("window_s") for f in res.get("filter", []))
    check = say(b.get("window_s") for b in res.get("validation_band", []))
    return f" [second filter: fit {fit}, check {check}]"


def joint_columns(frame: pd.DataFrame, prefix: str, unit: str) -> list[str]:
    return [c for c in frame.columns if c.startswith(prefix) and c.endswith(unit)
            and c[len(prefix):-len(unit)].strip("_").isdigit()]


def run_signals(run_dir: Path) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """A run's joints, q, qd (logged, else the Savitzky-Golay first derivative of q), qdd (Savitzky-Golay), tau
    and the filter's window in rows (rows within it of either end are not used)."""
    frame = pd.read_csv(run_dir / "data.csv")
    t_s = frame["t_s"].to_numpy()
    q_cols = joint_columns(frame, "q_", "_rad")
    joints = [int(c.split("_")[1]) for c in q_cols]
    q = frame[q_cols].to_numpy()
    dt_s = float(np.median(np.diff(t_s)))
    window = int(round(SAVGOL_WINDOW_S / dt_s)) | 1
    qd_cols = [f"qd_{j}_rad_s" for j in joints]
    qd = (frame[qd_cols].to_numpy() if all(c in frame for c in qd_cols)
          else savgol_filter(q, window, 3, deriv=1, delta=dt_s, axis=0))
    qdd = savgol_filter(q, window, 3, deriv=2, delta=dt_s, axis=0)
    tau = frame[[f"tau_{j}_Nm" for j in joints]].to_numpy()
    return joints, q, qd, qdd, tau, window


def datasheet_reference(run_dir: Path, holdout: float, robot: str = "wam7") -> dict:
    """Held-out torque of the robot's datasheet arm + friction fitted on the training part (all joints logged)."""
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.friction import FrictionModel

    dyn = WamDynamics(robot=robot)
    joints, q, qd, qdd, tau, window = run_signals(run_dir)
    if joints != list(range(1, dyn.n_joints + 1)):
        return {"skipped": f"the datasheet reference needs all {dyn.n_joints} joints of the {robot}; the log has "
                           f"{joints}"}
    n_rows = len(q)
    tau_rb = dyn.inverse_dynamics_many(q, qd, qdd)
    n_train = int(round(n_rows * (1.0 - holdout)))
    edge = window                                   # the filter's ends are not used
    train = slice(edge, n_train)
    test = slice(n_train, n_rows - edge)
    moving = [k for k in range(len(joints)) if np.ptp(q[:, k]) > MOVING_RANGE_RAD]
    fitted = tau_rb.copy()
    for k in range(len(joints)):
        basis = np.column_stack([np.sign(qd[:, k]), qd[:, k], np.ones_like(qd[:, k])])
        coef, *_ = np.linalg.lstsq(basis[train], (tau[:, k] - tau_rb[:, k])[train], rcond=None)
        fitted[:, k] += basis @ coef
    result = {"moving_joints": [joints[k] for k in moving], "train_rows": n_train - edge,
              "held_out_rows": n_rows - edge - n_train}
    declared = tau_rb + FrictionModel.table_4_1(dyn.n_joints).friction_torque(qd)
    for label, tau_hat in (("table_4_1_friction", declared), ("friction_fitted", fitted)):
        err = tau[test] - tau_hat[test]
        result[label] = {
            "rms_Nm": {joints[k]: round(float(np.sqrt(np.mean(err[:, k] ** 2))), 3) for k in moving},
            "relative_error_moving": round(float(np.linalg.norm(err[:, moving])
                                                 / np.linalg.norm(tau[test][:, moving])), 4),
            "relative_error_all": round(float(np.linalg.norm(err) / np.linalg.norm(tau[test])), 4)}
    return result


def joint1_reference(run_dir: Path, holdout: float) -> dict:
    """Joint 1 alone where it is the only joint moving: its axis is vertical, so its torque has no gravity
    and, the other joints held, no coupling; a constant inertia + Coulomb + viscous + offset fitted on the
    training part is what any friction or inertia estimate of joint 1 should reach held out."""
    frame = pd.read_csv(run_dir / "data.csv")
    q_cols = joint_columns(frame, "q_", "_rad")
    moving = [c for c in q_cols if np.ptp(frame[c].to_numpy()) > MOVING_RANGE_RAD]
    if moving != ["q_1_rad"]:
        return {"skipped": f"joints moving: {moving}, not joint 1 alone"}
    t_s = frame["t_s"].to_numpy()
    dt_s = float(np.median(np.diff(t_s)))
    window = int(round(SAVGOL_WINDOW_S / dt_s)) | 1
    q1 = frame["q_1_rad"].to_numpy()
    qd1 = frame["qd_1_rad_s"].to_numpy()
    tau1 = frame["tau_1_Nm"].to_numpy()
    qdd1 = savgol_filter(q1, window, 3, deriv=2, delta=dt_s)
    basis = np.column_stack([qdd1, np.sign(qd1), qd1, np.ones_like(qd1)])
    n_train = int(round(len(t_s) * (1.0 - holdout)))
    train, test = slice(window, n_train), slice(n_train, len(t_s) - window)
    coef, *_ = np.linalg.lstsq(basis[train], tau1[train], rcond=None)
    err = tau1[test] - basis[test] @ coef
    return {"train_rows": n_train - window, "held_out_rows": len(t_s) - window - n_train,
            "inertia_kg_m2": round(float(coef[0]), 4), "coulomb_Nm": round(float(coef[1]), 3),
            "viscous_Nm_s_rad": round(float(coef[2]), 3), "offset_Nm": round(float(coef[3]), 3),
            "rms_Nm": round(float(np.sqrt(np.mean(err ** 2))), 3),
            "relative_error": round(float(np.linalg.norm(err) / np.linalg.norm(tau1[test])), 4)}


def fit_datasheet_friction(run_dir: Path, robot: str) -> np.ndarray:
    """Per joint Coulomb, viscous and offset (N m, N m s/rad, N m) fitted by least squares beside the robot's
    datasheet arm on the whole of ``run_dir`` (a training part), the filter's ends left out: the reference any
    estimator must beat, fitted on the same rows as the estimators and checked on the same held-out rows."""
    from wamctl.model.dynamics import WamDynamics

    joints, q, qd, qdd, tau, window = run_signals(run_dir)
    rows = slice(window, len(q) - window)
    resid = tau - WamDynamics(robot=robot).inverse_dynamics_many(q, qd, qdd)
    coef = np.zeros((len(joints), 3))
    for k in range(len(joints)):
        basis = np.column_stack([np.sign(qd[:, k]), qd[:, k], np.ones_like(qd[:, k])])
        coef[k], *_ = np.linalg.lstsq(basis[rows], resid[rows, k], rcond=None)
    return coef


def model_torque(q, qd, qdd, model_file: Path | tuple | np.ndarray | None, robot: str = "wam7"):
    """Torque of the datasheet arm (``None``: Table 4.1 friction) or of a wamctl-model/1 file (links, friction and
    a payload effect, as `identify` and `diagnose` write them; what the file leaves out stays the datasheet's);
    a tuple: the wam7 datasheet arm with its wrist held at those joint angles (rad), Table 4.1 friction, the
    first ``q.shape[1]`` joints' torque; an array (joints x 3): the datasheet arm plus that Coulomb, viscous and
    offset per joint (`fit_datasheet_friction`)."""
    from wamctl.io import load_yaml
    from wamctl.model.dynamics import Payload, WamDynamics
    from wamctl.model.friction import FrictionModel
    from wamctl.model.params import LinkParameters

    if isinstance(model_file, tuple):
        n, rows = q.shape[1], len(q)
        pad = np.tile(np.asarray(model_file, float), (rows, 1))
        zero = np.zeros((rows, 7 - n))
        q7, qd7, qdd7 = (np.hstack([q, pad]), np.hstack([qd, zero]), np.hstack([qdd, zero]))
        tau7 = WamDynamics().inverse_dynamics_many(q7, qd7, qdd7) + FrictionModel.table_4_1().friction_torque(qd7)
        return tau7[:, :n]
    if isinstance(model_file, np.ndarray):
        basis = np.stack([np.sign(qd), qd, np.ones_like(qd)], axis=2)          # rows x joints x 3
        return WamDynamics(robot=robot).inverse_dynamics_many(q, qd, qdd) + np.einsum("rjk,jk->rj", basis, model_file)
    data = load_yaml(model_file) if model_file else {}
    links = LinkParameters.datasheet(robot).with_overrides(data.get("links"))
    load = (data.get("effects") or {}).get("payload")
    payload = Payload(float(load["mass_kg"]), tuple(load.get("com_m") or (0.0, 0.0, 0.0))) if load else None
    friction = (FrictionModel.from_dict(data["friction"], n_joints=q.shape[1]) if data.get("friction")
                else FrictionModel.table_4_1(q.shape[1]))
    return WamDynamics(payload=payload, links=links).inverse_dynamics_many(q, qd, qdd) + friction.friction_torque(qd)


def held_out_models(test_run: Path, models: dict[str, Path | tuple | np.ndarray | None], robot: str = "wam7") -> dict:
    """Each model's torque RMS per moving joint and relative error on the whole of ``test_run`` (a run kept out
    of every fit), unfiltered torque, Savitzky-Golay accelerations, the filter's ends left out."""
    joints, q, qd, qdd, tau, window = run_signals(test_run)
    rows = slice(window, len(q) - window)
    moving = [k for k in range(len(joints)) if np.ptp(q[:, k]) > MOVING_RANGE_RAD]
    out = {"rows": len(q) - 2 * window, "moving_joints": [joints[k] for k in moving]}
    for label, path in models.items():
        err = (tau - model_torque(q, qd, qdd, path, robot))[rows]
        out[label] = {"rms_Nm": {joints[k]: round(float(np.sqrt(np.mean(err[:, k] ** 2))), 3) for k in moving},
                      "relative_error_moving": round(float(np.linalg.norm(err[:, moving])
                                                           / np.linalg.norm(tau[rows][:, moving])), 4),
                      "relative_error_all": round(float(np.linalg.norm(err) / np.linalg.norm(tau[rows])), 4)}
    return out


def import_part(rec: Recording, path: Path, out: Path, name: str) -> Path:
    """A part of a recording written to ``path`` in its own format, imported as the recording is (no reference:
    the analyses let the measurement stand in for it)."""
    code, text = run(["import", str(path), *rec.import_args, "--robot", rec.robot, "--torque", rec.torque,
                      "--out", str(out), "--name", name, "--json"])
    if code != 0:
        raise SystemExit(f"import of {path}: {first_error(text)}")
    return Path(json.loads(text[text.index("{"):])["run_dir"])


def split_parts(source: Path, out: Path, holdout: float, rec: Recording) -> None:
    """identify and diagnose on the first part of a log without a reference (the analyses let the measured
    positions stand in for it), every model then checked on the last part, which no fit has seen; friction-id on
    the whole."""
    out.mkdir(parents=True, exist_ok=True)
    if source.suffix == ".json":
        records = json.loads(source.read_text())
        n_train = int(round(len(records) * (1.0 - holdout)))
        (out / "train.json").write_text(json.dumps(records[:n_train]))
        (out / "test.json").write_text(json.dumps(records[n_train:]))
        train = import_part(rec, out / "train.json", out / "runs", "train")
        test = import_part(rec, out / "test.json", out / "runs", "held-out")
        whole = None
    else:
        records = [ln for ln in source.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
        n_train = int(round(len(records) * (1.0 - holdout)))
        for name, part in (("train", records[:n_train]), ("test", records[n_train:]), ("whole", records)):
            (out / f"{name}.dat").write_text("\n".join(part) + "\n")
        train = import_part(rec, out / "train.dat", out / "runs", "train")
        test = import_part(rec, out / "test.dat", out / "runs", "held-out")
        whole = import_part(rec, out / "whole.dat", out / "runs", "whole")
    if whole is not None:
        code, text = run(["friction-id", "--data", str(whole), "--out", str(out / "analyses")])
        tail = first_error(text) if code != 0 else text.splitlines()[-1] if text else ""
        print(f"  wamctl friction-id --data (whole excerpt): exit {code}: {tail}")
    models: dict[str, Path | tuple | np.ndarray | None] = {
        "datasheet arm + Table 4.1 friction": None,
        "datasheet arm + friction fitted on the first part": fit_datasheet_friction(train, rec.robot)}
    if rec.held_wrist_rad is not None:
        models["wam7 datasheet arm, wrist held, + Table 4.1 friction"] = rec.held_wrist_rad
    for command in (["identify", str(train), "--validate", str(test)], ["diagnose", str(train)]):
        code, text = run([*command, "--out", str(out / "analyses"), "--json"])
        print(f"  wamctl {command[0]} (first part): exit {code}: {summary_line(command[0], code, text)}")
        answer = json_answer(text) if code in (0, 3) else None
        if answer is None:
            continue
        model_file = Path(answer.get("model_file") or Path(answer["run_dir"]) / "model.yaml")
        if model_file.exists():                     # identify's model_rejected.yaml too: what it refused, measured
            models[f"{command[0]}'s {model_file.name}"] = model_file
    print(f"  on the last {holdout:.0%} ({len(records) - n_train} records): "
          f"{json.dumps(held_out_models(test, models, rec.robot))}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder with one sub-folder per recording")
    parser.add_argument("--out", type=Path, default=Path("/tmp/wamctl-real-data"))
    parser.add_argument("--holdout", type=float, default=0.25)
    parser.add_argument("--only", action="append", default=None, metavar="NAME",
                        help="run only this recording (a sub-folder name; may be given more than once)")
    args = parser.parse_args()
    known = {rec.name for rec in RECORDINGS}
    for name in args.only or ():
        if name not in known:
            parser.error(f"--only {name}: not a recording here (known: {', '.join(sorted(known))})")
    args.out.mkdir(parents=True, exist_ok=True)
    for rec in RECORDINGS:
        if args.only and rec.name not in args.only:
            continue
        source = args.data / rec.name / rec.file
        print(f"## {rec.name}/{rec.file} ({rec.robot}, torque {rec.torque})")
        if not source.exists():
            print(f"  skipped: {source} not found "
                  f"(tests/fixtures/real/{rec.name}/PROVENANCE.md says how to rebuild it)")
            continue
        code, text = run(["import", str(source), *rec.import_args, "--robot", rec.robot,
                          "--torque", rec.torque, "--out", str(args.out / "runs"), "--json"])
        print(f"  wamctl import: exit {code}" + ("" if code == 0 else f": {first_error(text)}"))
        if code != 0:
            continue
        run_dir = Path(json.loads(text[text.index("{"):])["run_dir"])
        if rec.torque == "total":
            print(f"  datasheet arm + friction fitted, last {args.holdout:.0%} held out: "
                  f"{json.dumps(datasheet_reference(run_dir, args.holdout, rec.robot))}")
        else:
            print(f"  joint 1 alone, inertia + friction fitted, last {args.holdout:.0%} held out: "
                  f"{json.dumps(joint1_reference(run_dir, args.holdout))}")
        for command in (["identify"], ["friction-id", "--data"], ["diagnose"]):
            code, text = run([*command, str(run_dir), "--out", str(args.out / "analyses"), "--json"])
            print(f"  wamctl {' '.join(command)}: exit {code}: {summary_line(command[0], code, text)}")
        if rec.file.endswith((".json", ".dat")):
            split_parts(source, args.out / rec.name, args.holdout, rec)


if __name__ == "__main__":
    main()

"""The measured-run format (``wamctl-measured/1``, see docs/measured-run.md): import, export, loading.

A measured run is a directory with ``meta.yaml`` and ``data.parquet`` or ``data.csv`` (columns ``t``,
``q_ref_1..7``, ``q_1..7``, ``tau_1..7`` and optionally ``qd_1..7``). Inside wamctl the same data use the
run-directory column names (``t_s``, ``q_ref_{j}_rad``, ``q_{j}_rad``, ``tau_{j}_Nm``, ``qd_{j}_rad_s``), so
every analysis takes either a run directory or a measured-run directory through :func:`load_run_data`.

A measured run may name ``robot: wam4`` (libbarrett's 4-DOF arm) and may log a subset of the robot's joints
(``joints:``): the columns of joints not logged are absent, never zeros. Until the analyses take such runs (and
torques other than the total command), :func:`load_run_data` refuses them in one line, naming the command; the
report of an imported run reads what was logged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from wamctl.errors import DataFormatError
from wamctl.io import ensure_dir, load_yaml
from wamctl.model import params as P
from wamctl.model.robots import ROBOTS
from wamctl.runs.store import RunDir, open_run, read_table, write_csv

log = logging.getLogger(__name__)

FORMAT = "wamctl-measured/1"
J = range(1, P.N_JOINTS + 1)
MAX_NAN_FRACTION = 0.01
# consecutive NaN rows dropped as "isolated": dropping them leaves a hole of at most 4 samples, which the readers
# take like jitter (docs/measured-run.md); a longer block is an error naming its first and last row
MAX_NAN_BLOCK_ROWS = 4
# the joints of each robot a measured run may name (wamctl.model.robots: libbarrett's wam7w.conf / wam4.conf);
# the analyses that take any registered robot are in _ANY_ROBOT, the others know only the wam7 so far
ROBOT_JOINTS = {name: r.n_joints for name, r in ROBOTS.items()}
# what tau is: the whole command incl. gravity compensation (libbarrett's jtSum; the meaning when absent), the
# user's controller output with gravity compensation added downstream and not logged, or a torque sensor
TORQUE_KINDS = ("total", "controller", "measured")
# the quantities a measured run holds per joint: (name, unit suffix of the internal column); the first three
# are required (q_ref only when the log has a reference), the others optional
QUANTITIES = {"q_ref": "rad", "q": "rad", "tau": "Nm", "qd": "rad_s", "qd_ref": "rad_s", "qdd": "rad_s2",
              "qdd_ref": "rad_s2"}


class _Meta(BaseModel):
    model_config = ConfigDict(extra="allow")


class MeasuredController(_Meta):
    # unknown: an imported lab log whose controller is not described
    kind: Literal["pd_g", "pid", "pd_g_ff", "unknown"]
    # the gains may be unknown (a recording of someone else's controller): ``wamctl diagnose`` then estimates
    # them from the log; one per joint of the robot (checked in MeasuredMeta)
    kp: list[float] | None = None
    kd: list[float] | None = None
    ki: list[float] | None = None


class MeasuredExperiment(_Meta):
    kind: Literal["rotation", "sweep", "free"]
    joints: list[int]

    @field_validator("joints")
    @classmethod
    def _joints(cls, v):
        bad = [j for j in v if not 1 <= j <= P.N_JOINTS]
        if bad:
            raise ValueError(f"joint numbers are 1..7, got {bad}")
        return v


class MeasuredPayload(_Meta):
    mass_kg: float = Field(ge=0.0)
    com_m: list[float] = Field(min_length=3, max_length=3)


def _length_error(key: str, got: int, want: int) -> str:
    return f"{key}: List should have {'at least' if got < want else 'at most'} {want} items"


class MeasuredMeta(_Meta):
    format: Literal["wamctl-measured/1"]
    robot: Literal["wam7", "wam4"]
    sample_rate_hz: float = Field(gt=0)
    gravity_compensation: bool
    controller: MeasuredController
    experiment: MeasuredExperiment
    q0: list[float | None]       # null for a joint not logged
    payload: MeasuredPayload | None = None
    notes: Any = None
    joints: list[int] | None = None                                   # the joints logged; absent: all
    torque: Literal["total", "controller", "measured"] | None = None  # what tau is; absent: total

    @model_validator(mode="after")
    def _per_robot(self):
        n = ROBOT_JOINTS[self.robot]
        for key, v in (("q0", self.q0), ("controller.kp", self.controller.kp), ("controller.kd", self.controller.kd),
                       ("controller.ki", self.controller.ki)):
            if v is not None and len(v) != n:
                raise ValueError(_length_error(key, len(v), n))
        for key, js in (("joints", self.joints), ("experiment.joints", self.experiment.joints)):
            bad = [j for j in js or [] if not 1 <= j <= n]
            if bad:
                raise ValueError(f"{key}: joint numbers of {self.robot} are 1..{n}, got {bad}")
        if self.joints is not None:
            if not self.joints or sorted(set(self.joints)) != self.joints:
                raise ValueError(f"joints: expected joint numbers in increasing order, once each, got {self.joints}")
            missing = [i + 1 for i, v in enumerate(self.q0) if v is None and i + 1 in self.joints]
            if missing:
                raise ValueError(f"q0: null at joint(s) {missing}, which are logged")
        elif any(v is None for v in self.q0):
            raise ValueError("q0: null entries need joints: (the joints logged)")
        return self

    @property
    def logged_joints(self) -> list[int]:
        return list(self.joints) if self.joints is not None else list(range(1, ROBOT_JOINTS[self.robot] + 1))

    @property
    def torque_kind(self) -> str:
        return self.torque or "total"


@dataclass
class RunData:
    """Samples and metadata of a run, from a run directory or a measured-run directory."""

    meta: MeasuredMeta
    data: pd.DataFrame          # run-directory column names
    source: Path
    truth: dict | None = None   # the simulated plant's spec, when the run is ours and simulated

    @property
    def t_s(self) -> np.ndarray:
        return self.data["t_s"].to_numpy()

    @property
    def n_joints(self) -> int:
        """The joints of the robot the run names (7 for a wam7, 4 for a wam4)."""
        return ROBOT_JOINTS[self.meta.robot]

    def col(self, name: str) -> np.ndarray:
        """(n, 7) array of ``{name}_{j}_{unit}`` columns, e.g. ``col('q')``, ``col('q_ref')``, ``col('tau')``;
        NaN where a column is absent (a joint or a quantity not logged: never zeros)."""
        unit = QUANTITIES[name]
        n = len(self.data)
        return np.column_stack([self.data[c].to_numpy(float) if c in self.data else np.full(n, np.nan)
                                for c in (f"{name}_{j}_{unit}" for j in J)])


def internal_name(name: str, j: int) -> str:
    """The run-directory column of quantity ``name`` (a key of QUANTITIES) at joint ``j``: ``q_2_rad``."""
    return f"{name}_{j}_{QUANTITIES[name]}"


def _to_internal(df: pd.DataFrame) -> pd.DataFrame:
    ren = {"t": "t_s"}
    for j in J:
        ren.update({f"{name}_{j}": internal_name(name, j) for name in QUANTITIES})
    return df.rename(columns=ren)


def _to_external(df: pd.DataFrame) -> pd.DataFrame:
    cols = {"t_s": "t"}
    for name in ("q_ref", "q", "tau"):
        cols.update({internal_name(name, j): f"{name}_{j}" for j in J})
    return df[[c for c in cols if c in df]].rename(columns=cols)


def as_numbers(df: pd.DataFrame, source, row_name: str, column_name=None) -> pd.DataFrame:
    """``df`` with every cell a number (text read from a CSV converted; empty cells NaN), or DataFormatError naming
    the first cell that is not one: ``source: <row_name> <row>, column <name>: '<cell>' is not a number``, the row
    1-based, the column named by ``column_name(column)`` (default: the run's external name, ``q_3``; an importer
    gives the file's own)."""
    if all(pd.api.types.is_numeric_dtype(t) for t in df.dtypes):
        return df
    num = df.apply(pd.to_numeric, errors="coerce")
    bad = (num.isna() & df.notna()).to_numpy()
    if bad.any():
        row, col = map(int, np.argwhere(bad)[0])
        name = (column_name or _external_name)(df.columns[col])
        raise DataFormatError(f"{source}: {row_name} {row + 1}, column {name}: {str(df.iat[row, col])[:40]!r} is "
                              "not a number")
    return num


def _external_name(col: str) -> str:
    """The measured-run format's name of an internal column (``q_1_rad`` -> ``q_1``, ``t_s`` -> ``t``)."""
    if col == "t_s":
        return "t"
    for unit in ("_rad_s2", "_rad_s", "_rad", "_Nm"):
        if col.endswith(unit):
            return col[: -len(unit)]
    return col


def _separator_hint(columns) -> str:
    """A hint when the header looks like another separator than the comma."""
    head = ",".join(str(c) for c in columns)
    for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars")):
        if head.count(sep) >= 3:
            return (f" (the header is separated by {name}: data.csv must be comma-separated, with a dot as the "
                    "decimal mark)")
    return ""


def read_meta(path: Path) -> MeasuredMeta:
    mpath = path / "meta.yaml"
    if not mpath.is_file():
        raise DataFormatError(f"{path}: meta.yaml is missing")
    raw = load_yaml(mpath, DataFormatError)
    if not isinstance(raw, dict):
        raise DataFormatError(f"{mpath}: expected a mapping")
    try:
        return MeasuredMeta.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in err["loc"])
        msg = "missing" if err["type"] == "missing" else err["msg"].removeprefix("Value error, ")
        raise DataFormatError(f"{mpath}: {loc}: {msg}" if loc else f"{mpath}: {msg}") from None


def nan_blocks(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) 0-based indices of each run of True in ``mask``."""
    d = np.diff(np.concatenate([[0], np.asarray(mask, int), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist()))


def validate_samples(df: pd.DataFrame, sample_rate_hz: float | None, source: str, joints: list[int] | None = None,
                     row_name: str = "data row") -> pd.DataFrame:
    """Check the internal-named table: columns, NaNs, monotonic time, sample rate. Returns it cleaned.

    ``joints``: the joints logged (default all seven); their ``q``, ``tau`` and ``q_ref`` columns are required
    (``q_ref`` may be absent for every joint: a log without a reference), columns of other joints are an error.
    Row numbers in messages are the file's own, 1-based and counted before any NaN row is dropped; ``row_name``
    says what they count ("data row": the rows after the header; "line": lines of a file without one).
    """
    explicit = joints is not None
    joints = list(J) if joints is None else list(joints)
    reference = any(str(c).startswith("q_ref_") for c in df.columns)
    names = ("q_ref", "q", "tau") if reference else ("q", "tau")
    required = ["t_s"] + [internal_name(n, j) for n in names for j in joints]
    missing = [c for c in required if c not in df.columns]
    if missing:
        shown = [_external_name(c) for c in missing]
        raise DataFormatError(f"{source}: missing column(s): {', '.join(shown)}" + _separator_hint(df.columns))
    if explicit:
        stray = [(n, j) for n in QUANTITIES for j in J if j not in joints and internal_name(n, j) in df.columns]
        if stray:
            n, j = stray[0]
            raise DataFormatError(f"{source}: column {n}_{j} is present but joint {j} is not logged (the joints "
                                  f"logged: {', '.join(map(str, joints))})")
    optional = [internal_name(n, j) for n in QUANTITIES if n not in names for j in joints]
    cols = required + [c for c in optional if c in df.columns]
    df = as_numbers(df[cols], source, row_name).astype(float)
    inf = np.isinf(df.to_numpy())
    if inf.any():
        row, col = map(int, np.argwhere(inf)[0])
        raise DataFormatError(f"{source}: {row_name} {row + 1}, column {_external_name(cols[col])}: "
                              f"{df.iat[row, col]} is not a finite number")
    if len(df) < 10:
        raise DataFormatError(f"{source}: only {len(df)} rows; a run needs at least 10")
    rows = np.arange(1, len(df) + 1)                     # the file's own row numbers, kept through the drop
    nan_rows = df.isna().any(axis=1).to_numpy()
    if nan_rows.any():
        long = [(a, b) for a, b in nan_blocks(nan_rows) if b - a + 1 > MAX_NAN_BLOCK_ROWS]
        if long:
            a, b = long[0]
            raise DataFormatError(f"{source}: {row_name}s {a + 1}-{b + 1}: {b - a + 1} consecutive rows with NaN; "
                                  f"only isolated NaN rows (at most {MAX_NAN_BLOCK_ROWS} in a row) are dropped")
        frac = nan_rows.mean()
        if frac > MAX_NAN_FRACTION:
            first = int(np.argmax(nan_rows)) + 1
            raise DataFormatError(f"{source}: {int(nan_rows.sum())} rows with NaN ({frac:.1%}), first at {row_name} "
                                  f"{first}; at most {MAX_NAN_FRACTION:.0%} can be dropped")
        df = df[~nan_rows].reset_index(drop=True)
        rows = rows[~nan_rows]
    t = df["t_s"].to_numpy()
    dt = np.diff(t)
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0))
        raise DataFormatError(f"{source}: t is not strictly increasing at {row_name} {rows[k + 1]} "
                              f"(t = {t[k]:.6g} then {t[k + 1]:.6g})")
    rate = 1.0 / np.median(dt)
    if sample_rate_hz is not None and abs(rate - sample_rate_hz) > 0.05 * sample_rate_hz:
        raise DataFormatError(f"{source}: sample_rate_hz is {sample_rate_hz:g} but t says {rate:.1f} Hz "
                              f"(more than 5 % apart)")
    if nan_rows.any():           # said once the file is accepted: an error stays the one line
        log.warning("%s: dropped %d rows with NaN values", source, int(nan_rows.sum()))
    return df


def read_measured(path: str | Path) -> RunData:
    """Load and validate a measured-run directory."""
    path = Path(path)
    if not path.is_dir():
        raise DataFormatError(f"{path}: no such directory")
    meta = read_meta(path)
    if (path / "data.parquet").is_file():
        try:
            df = pd.read_parquet(path / "data.parquet")
        except Exception as exc:  # pyarrow raises several types for truncated files
            raise DataFormatError(f"{path / 'data.parquet'}: unreadable Parquet ({exc})") from None
        src = path / "data.parquet"
    elif (path / "data.csv").is_file():
        try:
            df = pd.read_csv(path / "data.csv", low_memory=False)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if isinstance(exc, UnicodeDecodeError):
                msg = f"not UTF-8 text (byte 0x{exc.object[exc.start]:02x})"
            raise DataFormatError(f"{path / 'data.csv'}: unreadable CSV ({msg})") from None
        src = path / "data.csv"
    else:
        raise DataFormatError(f"{path}: neither data.parquet nor data.csv")
    df = validate_samples(_to_internal(df), meta.sample_rate_hz, str(src), meta.logged_joints)
    return RunData(meta, df, path)


def meta_from_run(manifest: dict, spec: dict, data: pd.DataFrame) -> MeasuredMeta:
    """Describe one of our run directories in measured-run terms."""
    c = spec.get("controller") or {}
    robot = ROBOTS[spec.get("robot") or "wam7"]      # the spec's arm (its default gains, its joints)
    kp = c.get("kp") or robot.kp.tolist()
    kd = c.get("kd") or robot.kd.tolist()
    ki = (c.get("ki") or robot.ki.tolist()) if c.get("kind") == "pid" else [0.0] * robot.n_joints
    kind = manifest.get("kind")
    exp_kind = {"rotation": "rotation", "friction_sweep": "sweep"}.get(kind, "free")
    moved = [j for j in range(1, robot.n_joints + 1) if np.ptp(data[f"q_ref_{j}_rad"].to_numpy()) > 1e-9]
    payload = c.get("declared_payload")
    return MeasuredMeta(format=FORMAT, robot=robot.name, sample_rate_hz=P.CONTROL_RATE_HZ,
                        gravity_compensation=bool(c.get("gravity_compensation", True)),
                        controller={"kind": c.get("kind", "pd_g"), "kp": kp, "kd": kd, "ki": ki},
                        experiment={"kind": exp_kind, "joints": moved}, q0=spec.get("q0_rad"),
                        payload=payload, notes=f"exported by wamctl from run {manifest.get('name')}",
                        source_run_kind=kind)


def unsupported(meta: MeasuredMeta, columns, any_robot: bool = False, controller_ok: bool = False) -> str | None:
    """Why the analyses cannot take a run yet (None: they can): they know the wam7 (``any_robot``: every
    registered robot) with all its joints, and tau the total command (``controller_ok``: also the controller's
    output, the caller using only the joints whose gravity torque is constant over the run). A log without a
    reference is taken with the measurement standing in for it (:func:`with_reference`) by the readers that say
    so (:func:`load_run_data`'s ``stand_in``)."""
    if meta.robot != "wam7" and not any_robot:
        return f"robot {meta.robot}"
    n = ROBOT_JOINTS[meta.robot]
    absent = [j for j in range(1, n + 1) if j not in meta.logged_joints]
    if absent:
        return (f"joint(s) {', '.join(map(str, absent))} not logged (the analyses need all {n} joints of "
                f"the {meta.robot})")
    if meta.torque_kind != "total" and not (controller_ok and meta.torque_kind == "controller"):
        what = {"controller": "the controller's output, gravity compensation added downstream and not logged",
                "measured": "a torque sensor's reading"}[meta.torque_kind]
        return f"torque {meta.torque_kind} ({what})"
    return None


# what stands in for a reference a log does not hold (lab logs rarely do: wam_node's JointState, a recorder's table)
NO_REFERENCE = ("no reference (q_ref) logged: the measured positions stand in for it (identify fits by least "
                "squares, diagnose skips the closed-loop position check, friction-id finds the moves in the "
                "measured motion)")


def has_reference(columns) -> bool:
    return any(str(c).startswith("q_ref_") for c in columns)


def with_reference(rd: RunData) -> RunData:
    """``rd`` as it is when it logged a reference, else with the measurement standing in for it (said on the
    terminal: :data:`NO_REFERENCE`)."""
    if has_reference(rd.data.columns):
        return rd
    log.warning("%s: %s", rd.source, NO_REFERENCE)
    return reference_from_measurement(rd)


def reference_from_measurement(rd: RunData) -> RunData:
    """A run without a logged reference, its measured positions (and velocities, where logged) standing in for
    the reference; ``meta.reference`` says so (``"measured"``) for the analyses that use the reference for more
    than the motion: identify's instruments (least squares instead), diagnose's closed-loop position check
    (skipped)."""
    df = rd.data.copy()
    for j in rd.meta.logged_joints:
        df[internal_name("q_ref", j)] = df[internal_name("q", j)]
        if internal_name("qd", j) in df and internal_name("qd_ref", j) not in df:
            df[internal_name("qd_ref", j)] = df[internal_name("qd", j)]
    return RunData(rd.meta.model_copy(update={"reference": "measured"}), df, rd.source, rd.truth)


def load_run_data(path: str | Path, partial_ok: bool = False, *, reader: str = "this analysis",
                  any_robot: bool = False, controller_ok: bool = False, stand_in: bool = False) -> RunData:
    """Either a run directory (ours) or a measured-run directory, as :class:`RunData`, for the command ``reader``
    (the name a user typed, for the one line that refuses a run).

    What the reader can take is its own to say: ``any_robot`` and ``controller_ok`` as :func:`unsupported`;
    ``stand_in``: a log without a reference is taken with the measurement standing in for it
    (:func:`with_reference`: identify, diagnose, friction-id and their reports; tune-ift's objective is the
    tracking error, which a stand-in would make zero). A run the reader cannot take is refused in one line naming
    ``reader``. ``partial_ok``: what was logged, as it was logged, nothing checked (the report of an imported run,
    export)."""
    path = Path(path)
    if (path / "meta.yaml").is_file():
        rd = read_measured(path)
    else:
        if path.is_dir() and not (path / "manifest.json").is_file():
            raise DataFormatError(f"{path}: neither a measured run (meta.yaml + data) nor a wamctl run directory "
                                  "(manifest.json)")
        manifest, spec = open_run(path)
        data = read_table(path)
        if "t_s" not in data or len(data) < 10:
            raise DataFormatError(f"{path}: the run holds {len(data)} samples; nothing to analyse")
        if spec.get("measured_meta"):  # an imported measured run keeps its own metadata
            meta = MeasuredMeta.model_validate(spec["measured_meta"])
        else:
            meta = meta_from_run(manifest, spec, data)
        truth = spec.get("plant") if (manifest.get("backend") or {}).get("name") == "sim" else None
        rd = RunData(meta, data, path, truth)
    if partial_ok:
        return rd
    why = unsupported(rd.meta, rd.data.columns, any_robot=any_robot, controller_ok=controller_ok)
    if why is None and not stand_in and not has_reference(rd.data.columns):
        why = "no reference (q_ref) logged"
    if why:
        raise DataFormatError(f"{path}: {why}: not supported by {reader} yet")
    return with_reference(rd)


def export_run(run_path: str | Path, to: str | Path, fmt: str = "parquet") -> Path:
    """Write a run directory in the measured-run format (``meta.yaml`` + ``data.parquet`` or ``data.csv``)."""
    rd = load_run_data(run_path, partial_ok=True)     # a wam4 or a subset of joints exports as it was logged
    to = ensure_dir(to, "export directory")
    meta = rd.meta.model_dump(mode="json", exclude_none=False)
    for key in ("joints", "torque"):                   # optional keys: absent when they say the default
        if meta.get(key) is None:
            meta.pop(key, None)
    (to / "meta.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    ext = _to_external(rd.data)
    if fmt == "csv":
        write_csv(ext, to / "data.csv")
    else:
        ext.to_parquet(to / "data.parquet", index=False)
    return to


def import_measured(path: str | Path, out_dir: str | Path = "runs", name: str | None = None) -> Path:
    """Validate a measured run and store it as a run directory (kind from its experiment), so that every
    analysis and report takes it like a run of ours."""
    return store_measured(read_measured(path), out_dir, name or Path(path).name, str(Path(path).resolve()))


def store_measured(rd: RunData, out_dir: str | Path, name: str, imported_from: str) -> Path:
    """Store validated measured data as a run directory (``kind`` from the experiment; ``measured`` for a run the
    analyses cannot take yet, whose report shows what was logged)."""
    m = rd.meta
    kind = {"rotation": "rotation", "sweep": "friction_sweep"}.get(m.experiment.kind, "measured")
    if unsupported(m, rd.data.columns):
        kind = "measured"
    spec = {"kind": kind, "name": name, "q0_rad": m.q0,
            "controller": {"kind": m.controller.kind, "kp": m.controller.kp, "kd": m.controller.kd,
                           "ki": m.controller.ki if m.controller.kind == "pid" else None,
                           "gravity_compensation": m.gravity_compensation,
                           "declared_payload": m.payload.model_dump() if m.payload else None},
            "measured_meta": m.model_dump(mode="json")}
    run = RunDir.create(out_dir, spec["name"], spec, None, kind,
                        {"backend": {"name": "measured"}, "imported_from": imported_from})
    run.write_table("data", rd.data)
    run.finish("completed", None)
    return run.path

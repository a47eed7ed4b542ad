"""The measured-run format (``wamctl-measured/1``, see docs/measured-run.md): import, export, loading.

A measured run is a directory with ``meta.yaml`` and ``data.parquet`` or ``data.csv`` (columns ``t``,
``q_ref_1..7``, ``q_1..7``, ``tau_1..7`` and optionally ``qd_1..7``). Inside wamctl the same data use the
run-directory column names (``t_s``, ``q_ref_{j}_rad``, ``q_{j}_rad``, ``tau_{j}_Nm``, ``qd_{j}_rad_s``), so
every analysis takes either a run directory or a measured-run directory through :func:`load_run_data`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from wamctl.errors import DataFormatError
from wamctl.model import params as P
from wamctl.io import ensure_dir, load_yaml
from wamctl.runs.store import RunDir, open_run, read_table, write_csv

log = logging.getLogger(__name__)

FORMAT = "wamctl-measured/1"
J = range(1, P.N_JOINTS + 1)
MAX_NAN_FRACTION = 0.01
_Vec7 = Field(min_length=P.N_JOINTS, max_length=P.N_JOINTS)


class _Meta(BaseModel):
    model_config = ConfigDict(extra="allow")


class MeasuredController(_Meta):
    kind: Literal["pd_g", "pid", "pd_g_ff"]
    # the gains may be unknown (a recording of someone else's controller): ``wamctl diagnose`` then estimates
    # them from the log
    kp: list[float] | None = Field(None, min_length=P.N_JOINTS, max_length=P.N_JOINTS)
    kd: list[float] | None = Field(None, min_length=P.N_JOINTS, max_length=P.N_JOINTS)
    ki: list[float] | None = Field(None, min_length=P.N_JOINTS, max_length=P.N_JOINTS)


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


class MeasuredMeta(_Meta):
    format: Literal["wamctl-measured/1"]
    robot: Literal["wam7"]
    sample_rate_hz: float = Field(gt=0)
    gravity_compensation: bool
    controller: MeasuredController
    experiment: MeasuredExperiment
    q0: list[float] = _Vec7
    payload: MeasuredPayload | None = None
    notes: Any = None


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

    def col(self, name: str) -> np.ndarray:
        """(n, 7) array of ``{name}_{j}_{unit}`` columns, e.g. ``col('q')``, ``col('q_ref')``, ``col('tau')``."""
        unit = {"q": "rad", "q_ref": "rad", "tau": "Nm", "qd": "rad_s"}[name]
        return self.data[[f"{name}_{j}_{unit}" for j in J]].to_numpy()


def _to_internal(df: pd.DataFrame) -> pd.DataFrame:
    ren = {"t": "t_s"}
    for j in J:
        ren.update({f"q_ref_{j}": f"q_ref_{j}_rad", f"q_{j}": f"q_{j}_rad", f"tau_{j}": f"tau_{j}_Nm",
                    f"qd_{j}": f"qd_{j}_rad_s"})
    return df.rename(columns=ren)


def _to_external(df: pd.DataFrame) -> pd.DataFrame:
    cols = {"t_s": "t"}
    for j in J:
        cols.update({f"q_ref_{j}_rad": f"q_ref_{j}", f"q_{j}_rad": f"q_{j}", f"tau_{j}_Nm": f"tau_{j}"})
    return df[list(cols)].rename(columns=cols)


def _external_name(col: str) -> str:
    """The measured-run format's name of an internal column (``q_1_rad`` -> ``q_1``, ``t_s`` -> ``t``)."""
    if col == "t_s":
        return "t"
    for unit in ("_rad_s", "_rad", "_Nm"):
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
        raise DataFormatError(f"{mpath}: {loc}: {msg}") from None


def validate_samples(df: pd.DataFrame, sample_rate_hz: float, source: str) -> pd.DataFrame:
    """Check the internal-named table: columns, NaNs, monotonic time, sample rate. Returns it cleaned."""
    required = ["t_s"] + [f"{n}_{j}_{u}" for n, u in (("q_ref", "rad"), ("q", "rad"), ("tau", "Nm")) for j in J]
    missing = [c for c in required if c not in df.columns]
    if missing:
        ext = {c: c.rsplit("_", 1)[0] if not c.endswith("Nm") else c[:-3] for c in missing}
        shown = [("t" if c == "t_s" else ext[c]) for c in missing]
        raise DataFormatError(f"{source}: missing column(s): {', '.join(shown)}" + _separator_hint(df.columns))
    cols = required + [c for c in df.columns if c.startswith("qd_") and c not in required]
    df = df[cols]
    if not all(pd.api.types.is_numeric_dtype(t) for t in df.dtypes):     # text (a CSV): every cell a number?
        num = df.apply(pd.to_numeric, errors="coerce")
        bad = num.isna() & df.notna()
        if bad.to_numpy().any():
            row, col = map(int, np.argwhere(bad.to_numpy())[0])
            name = _external_name(cols[col])
            raise DataFormatError(f"{source}: data row {row + 1}, column {name}: {str(df.iat[row, col])[:40]!r} is "
                                  "not a number")
        df = num
    df = df.astype(float)
    inf = np.isinf(df.to_numpy())
    if inf.any():
        row, col = map(int, np.argwhere(inf)[0])
        raise DataFormatError(f"{source}: data row {row + 1}, column {_external_name(cols[col])}: "
                              f"{df.iat[row, col]} is not a finite number")
    if len(df) < 10:
        raise DataFormatError(f"{source}: only {len(df)} rows; a run needs at least 10")
    nan_rows = df[required].isna().any(axis=1)
    if nan_rows.any():
        frac = nan_rows.mean()
        if frac > MAX_NAN_FRACTION:
            first = int(np.argmax(nan_rows.to_numpy())) + 1
            raise DataFormatError(f"{source}: {int(nan_rows.sum())} rows with NaN ({frac:.1%}), first at data row "
                                  f"{first}; at most {MAX_NAN_FRACTION:.0%} can be dropped")
        log.warning("%s: dropped %d rows with NaN values", source, int(nan_rows.sum()))
        df = df[~nan_rows].reset_index(drop=True)
    t = df["t_s"].to_numpy()
    dt = np.diff(t)
    if (dt <= 0).any():
        row = int(np.argmax(dt <= 0)) + 2
        raise DataFormatError(f"{source}: t is not strictly increasing at data row {row} "
                              f"(t = {t[row - 2]:.6g} then {t[row - 1]:.6g})")
    rate = 1.0 / np.median(dt)
    if abs(rate - sample_rate_hz) > 0.05 * sample_rate_hz:
        raise DataFormatError(f"{source}: sample_rate_hz is {sample_rate_hz:g} but t says {rate:.1f} Hz "
                              f"(more than 5 % apart)")
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
    df = validate_samples(_to_internal(df), meta.sample_rate_hz, str(src))
    return RunData(meta, df, path)


def meta_from_run(manifest: dict, spec: dict, data: pd.DataFrame) -> MeasuredMeta:
    """Describe one of our run directories in measured-run terms."""
    c = spec.get("controller") or {}
    kp = c.get("kp") or P.KP.tolist()
    kd = c.get("kd") or P.KD.tolist()
    ki = (c.get("ki") or P.KI.tolist()) if c.get("kind") == "pid" else [0.0] * P.N_JOINTS
    kind = manifest.get("kind")
    exp_kind = {"rotation": "rotation", "friction_sweep": "sweep"}.get(kind, "free")
    moved = [j for j in J if np.ptp(data[f"q_ref_{j}_rad"].to_numpy()) > 1e-9]
    payload = c.get("declared_payload")
    return MeasuredMeta(format=FORMAT, robot="wam7", sample_rate_hz=P.CONTROL_RATE_HZ,
                        gravity_compensation=bool(c.get("gravity_compensation", True)),
                        controller={"kind": c.get("kind", "pd_g"), "kp": kp, "kd": kd, "ki": ki},
                        experiment={"kind": exp_kind, "joints": moved}, q0=spec.get("q0_rad"),
                        payload=payload, notes=f"exported by wamctl from run {manifest.get('name')}",
                        source_run_kind=kind)


def load_run_data(path: str | Path) -> RunData:
    """Either a run directory (ours) or a measured-run directory, as :class:`RunData`."""
    path = Path(path)
    if (path / "meta.yaml").is_file():
        return read_measured(path)
    manifest, spec = open_run(path)
    data = read_table(path)
    if "t_s" not in data or len(data) < 10:
        raise DataFormatError(f"{path}: the run holds {len(data)} samples; nothing to analyse")
    if spec.get("measured_meta"):  # an imported measured run keeps its own metadata
        meta = MeasuredMeta.model_validate(spec["measured_meta"])
    else:
        meta = meta_from_run(manifest, spec, data)
    truth = spec.get("plant") if (manifest.get("backend") or {}).get("name") == "sim" else None
    return RunData(meta, data, path, truth)


def export_run(run_path: str | Path, to: str | Path, fmt: str = "parquet") -> Path:
    """Write a run directory in the measured-run format (``meta.yaml`` + ``data.parquet`` or ``data.csv``)."""
    rd = load_run_data(run_path)
    to = ensure_dir(to, "export directory")
    meta = rd.meta.model_dump(mode="json", exclude_none=False)
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
    rd = read_measured(path)
    m = rd.meta
    kind = {"rotation": "rotation", "sweep": "friction_sweep"}.get(m.experiment.kind, "measured")
    spec = {"kind": kind, "name": name or Path(path).name, "q0_rad": m.q0,
            "controller": {"kind": m.controller.kind, "kp": m.controller.kp, "kd": m.controller.kd,
                           "ki": m.controller.ki if m.controller.kind == "pid" else None,
                           "gravity_compensation": m.gravity_compensation,
                           "declared_payload": m.payload.model_dump() if m.payload else None},
            "measured_meta": m.model_dump(mode="json")}
    run = RunDir.create(out_dir, spec["name"], spec, None, kind,
                        {"backend": {"name": "measured"}, "imported_from": str(Path(path).resolve())})
    run.write_table("data", rd.data)
    run.finish("completed", None)
    return run.path

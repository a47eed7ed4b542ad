"""Read and validate gaze-HMI result files: raw trials or per-unit summaries, into :class:`HmiResults`.

Errors in a file raise :class:`wamctl.errors.DataFormatError` whose message names the file, the 1-based data row
(the header is not counted, nor are blank lines and ``#`` comment lines), the line number, and the column.
Conventions of the results themselves (units, conditions, proportions and percentages, missing cells): see
:mod:`wamctl.analysis.hmi_results`.

File formats (CSV, UTF-8, comma-separated, one header line, full-line ``#`` comments allowed)
-------------------------------------------------------------------------------------------------
Raw trials, one row per attempt::

    subject,condition,location,attempt,hit,time_s
    S1,E1,P1,1,1,23.4

=========  ======================================================================
column     meaning
=========  ======================================================================
subject    subject id (text)
condition  condition label (text), e.g. ``E1`` or ``MA300``
location   target location label (text), e.g. ``P1``
attempt    attempt number, integer >= 1; unique per (subject, condition, location)
hit        1/0 (also true/false, yes/no)
time_s     execution time of the attempt in seconds, > 0; may be empty (not recorded)
note       optional free text, ignored
=========  ======================================================================

Per-unit summaries, one row per (unit, condition)::

    subject,condition,hit_pct,mean_time_s
    1,E1,37,27.3

===========  ====================================================================
column       meaning
===========  ====================================================================
subject or   the unit: exactly one of the two columns
location
condition    condition label
hits         number of hits (integer >= 0), together with ``attempts``
attempts     number of attempts (integer >= 1, >= hits)
hit_pct      hit percentage 0-100, instead of ``hits``/``attempts`` (not both)
mean_time_s  mean execution time in seconds, > 0
note         optional free text, ignored
===========  ====================================================================

At least one measure (``hits``/``attempts``, ``hit_pct`` or ``mean_time_s``) must be present. An empty numeric
cell, ``-``, ``NA``, ``N/A`` or ``nan`` is a missing value (the thesis prints ``-``); a missing cell can also be
written by leaving the row out. Text cells (unit, condition) must not be empty.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from wamctl.analysis.hmi_results import TRIAL_COLUMNS, HmiResults, summarise_trials
from wamctl.errors import DataFormatError

logger = logging.getLogger(__name__)

SUMMARY_COLUMNS: tuple[str, ...] = ("subject", "location", "condition", "hits", "attempts", "hit_pct",
                                    "mean_time_s")
"""Columns a per-unit summary CSV may have (plus ``note``)."""

_MISSING = {"", "-", "na", "n/a", "nan"}  # numeric cells; a text cell is missing only if empty
_TRUE = {"1", "true", "yes", "y"}
_FALSE = {"0", "false", "no", "n"}


@dataclass(frozen=True)
class _Row:
    number: int  # 1-based data row
    line: int  # 1-based line in the file
    cells: dict[str, str]


def _where(source: str, row: _Row, column: str | None = None) -> str:
    col = f", column {column!r}" if column else ""
    return f"{source}: data row {row.number} (line {row.line}){col}"


def _read_csv(path: Path) -> tuple[list[str], list[_Row]]:
    """Read header and data rows, skipping blank lines and full-line ``#`` comments."""
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise DataFormatError(f"{source}: no such file") from None
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{source}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    lines = text.splitlines()
    header: list[str] | None = None
    header_line = 0
    rows: list[_Row] = []
    for line_no, fields in _csv_records(lines):
        if not fields or all(not f.strip() for f in fields) or fields[0].lstrip().startswith("#"):
            continue
        cells = [f.strip() for f in fields]
        if header is None:
            header, header_line = cells, line_no
            if any(not h for h in header):
                raise DataFormatError(f"{source}: line {line_no}: empty column name in header")
            dup = sorted({h for h in header if header.count(h) > 1})
            if dup:
                raise DataFormatError(f"{source}: line {line_no}: duplicate column(s) {dup} in header")
            continue
        row = _Row(len(rows) + 1, line_no, {})
        if len(cells) != len(header):
            raise DataFormatError(f"{_where(source, row)}: expected {len(header)} fields as in the header "
                                  f"(line {header_line}), got {len(cells)}")
        rows.append(_Row(row.number, line_no, dict(zip(header, cells))))
    if header is None:
        raise DataFormatError(f"{source}: no header line (file is empty or only comments)")
    if not rows:
        raise DataFormatError(f"{source}: header but no data rows")
    return header, rows


def _csv_records(lines: list[str]) -> list[tuple[int, list[str]]]:
    """Parse lines with :mod:`csv`, returning (first line number, fields) per record."""
    out = []
    reader = csv.reader(lines)
    start = 1
    for fields in reader:
        out.append((start, fields))
        start = reader.line_num + 1
    return out


def _is_missing(value: str) -> bool:
    return value.strip().lower() in _MISSING


def _text(source: str, row: _Row, column: str) -> str:
    value = row.cells[column]
    if not value:
        raise DataFormatError(f"{_where(source, row, column)}: value required, cell is empty")
    return value


def _float(source: str, row: _Row, column: str, *, minimum: float | None = None, exclusive: bool = False,
           maximum: float | None = None, required: bool = False) -> float:
    value = row.cells[column]
    if _is_missing(value):
        if required:
            raise DataFormatError(f"{_where(source, row, column)}: value required, cell is empty")
        return math.nan
    try:
        x = float(value)
    except ValueError:
        raise DataFormatError(f"{_where(source, row, column)}: expected a number, got {value!r}") from None
    if not math.isfinite(x):
        raise DataFormatError(f"{_where(source, row, column)}: expected a finite number, got {value!r}")
    if minimum is not None and (x < minimum or (exclusive and x == minimum)):
        relation = ">" if exclusive else ">="
        raise DataFormatError(f"{_where(source, row, column)}: expected {relation} {minimum:g}, got {value!r}")
    if maximum is not None and x > maximum:
        raise DataFormatError(f"{_where(source, row, column)}: expected <= {maximum:g}, got {value!r}")
    return x


def _int(source: str, row: _Row, column: str, *, minimum: int, required: bool = False) -> float:
    x = _float(source, row, column, minimum=minimum, required=required)
    if math.isfinite(x) and x != round(x):
        raise DataFormatError(f"{_where(source, row, column)}: expected an integer, got {row.cells[column]!r}")
    return x


def _check_columns(source: str, header: Sequence[str], allowed: Sequence[str], required: Sequence[str]) -> None:
    missing = [c for c in required if c not in header]
    if missing:
        raise DataFormatError(f"{source}: missing column(s) {missing}; header is {list(header)}")
    unknown = [c for c in header if c not in allowed and c != "note"]
    if unknown:
        raise DataFormatError(f"{source}: unknown column(s) {unknown}; allowed: {list(allowed) + ['note']}")


def _check_unique(source: str, rows: Sequence[_Row], keys: Sequence[tuple[str, ...]], names: Sequence[str]) -> None:
    first: dict[tuple[str, ...], _Row] = {}
    for row, key in zip(rows, keys):
        if key in first:
            what = ", ".join(f"{n}={v!r}" for n, v in zip(names, key))
            raise DataFormatError(f"{_where(source, row)}: duplicate of data row {first[key].number} ({what})")
        first[key] = row


def read_trials_csv(path: str | Path) -> pd.DataFrame:
    """Read and validate a raw-trials CSV.

    Parameters
    ----------
    path : str or pathlib.Path
        CSV with columns ``subject, condition, location, attempt, hit, time_s`` (and optional ``note``).

    Returns
    -------
    pandas.DataFrame
        Columns ``subject, condition, location`` (str), ``attempt`` (int), ``hit`` (int 0/1), ``time_s`` (float,
        NaN if not recorded), ``data_row`` (1-based).

    Raises
    ------
    DataFormatError
        Missing/unknown column, bad cell (the message names data row, line and column), duplicate attempt.
    """
    path = Path(path)
    source = str(path)
    header, rows = _read_csv(path)
    _check_columns(source, header, TRIAL_COLUMNS, TRIAL_COLUMNS)
    records = []
    for row in rows:
        hit_text = _text(source, row, "hit").lower()
        if hit_text in _TRUE:
            hit = 1
        elif hit_text in _FALSE:
            hit = 0
        else:
            raise DataFormatError(f"{_where(source, row, 'hit')}: expected 1/0 (true/false, yes/no), "
                                  f"got {row.cells['hit']!r}")
        records.append({
            "subject": _text(source, row, "subject"),
            "condition": _text(source, row, "condition"),
            "location": _text(source, row, "location"),
            "attempt": int(_int(source, row, "attempt", minimum=1, required=True)),
            "hit": hit,
            "time_s": _float(source, row, "time_s", minimum=0.0, exclusive=True),
            "data_row": row.number,
        })
    keys = [(r["subject"], r["condition"], r["location"], str(r["attempt"])) for r in records]
    _check_unique(source, rows, keys, ("subject", "condition", "location", "attempt"))
    frame = pd.DataFrame.from_records(records)
    logger.debug("%s: %d trials, %d subjects, %d conditions", source, len(frame), frame["subject"].nunique(),
                 frame["condition"].nunique())
    return frame


def read_summary_csv(path: str | Path) -> HmiResults:
    """Read and validate a per-unit summary CSV (one row per unit and condition).

    Parameters
    ----------
    path : str or pathlib.Path
        CSV with ``subject`` or ``location``, ``condition`` and measures (see the module docstring).

    Returns
    -------
    HmiResults

    Raises
    ------
    DataFormatError
        Unit column absent or both present, unknown column, ``hit_pct`` together with ``hits``/``attempts``, no
        measure, bad cell (naming data row, line and column), duplicate (unit, condition).
    """
    path = Path(path)
    source = str(path)
    header, rows = _read_csv(path)
    units = [c for c in ("subject", "location") if c in header]
    if len(units) != 1:
        raise DataFormatError(f"{source}: a summary needs exactly one unit column, 'subject' or 'location'; "
                              f"header is {header}")
    unit_kind = units[0]
    _check_columns(source, header, SUMMARY_COLUMNS, (unit_kind, "condition"))
    has_counts = "hits" in header or "attempts" in header
    if has_counts and not ("hits" in header and "attempts" in header):
        raise DataFormatError(f"{source}: columns 'hits' and 'attempts' go together; header is {header}")
    if has_counts and "hit_pct" in header:
        raise DataFormatError(f"{source}: give either 'hits'+'attempts' or 'hit_pct', not both")
    if not (has_counts or "hit_pct" in header or "mean_time_s" in header):
        raise DataFormatError(f"{source}: no measure column; need 'hits'+'attempts', 'hit_pct' or 'mean_time_s'")
    records = []
    for row in rows:
        hits = attempts = pct = math.nan
        if has_counts:
            hits = _int(source, row, "hits", minimum=0)
            attempts = _int(source, row, "attempts", minimum=1)
            if math.isnan(hits) != math.isnan(attempts):
                col = "attempts" if math.isnan(attempts) else "hits"
                raise DataFormatError(f"{_where(source, row, col)}: value required when "
                                      f"{'hits' if col == 'attempts' else 'attempts'} is given")
            if hits > attempts:
                raise DataFormatError(f"{_where(source, row, 'hits')}: {hits:g} hits > {attempts:g} attempts")
            rate = hits / attempts
        elif "hit_pct" in header:
            pct = _float(source, row, "hit_pct", minimum=0.0, maximum=100.0)
            rate = pct / 100.0
        else:
            rate = math.nan
        time_s = _float(source, row, "mean_time_s", minimum=0.0, exclusive=True) if "mean_time_s" in header \
            else math.nan
        records.append({unit_kind: _text(source, row, unit_kind), "condition": _text(source, row, "condition"),
                        "hits": hits, "attempts": attempts, "hit_rate": rate,
                        "hit_pct": rate * 100.0 if not math.isnan(rate) else pct, "mean_time_s": time_s})
    _check_unique(source, rows, [(r[unit_kind], r["condition"]) for r in records], (unit_kind, "condition"))
    measures = []
    if has_counts or "hit_pct" in header:
        measures += ["hit_rate", "hit_pct"]
    if "mean_time_s" in header:
        measures.append("mean_time_s")
    return HmiResults(data=pd.DataFrame.from_records(records), unit_kind=unit_kind, measures=tuple(measures),
                      source=source)



def read_hmi_csv(path: str | Path, *, unit: str | None = None) -> HmiResults:
    """Read HMI results, raw trials or per-unit summaries (recognised by the ``attempt`` and ``hit`` columns).

    Parameters
    ----------
    path : str or pathlib.Path
        CSV file in one of the formats of the module docstring.
    unit : {"subject", "location"}, optional
        For raw trials only: the unit to summarise by. Default: ``"subject"`` if the file has more than one
        subject, else ``"location"``.

    Returns
    -------
    HmiResults

    Raises
    ------
    DataFormatError
        See :func:`read_trials_csv` and :func:`read_summary_csv`.
    """
    path = Path(path)
    header, _ = _read_csv(path)
    if "attempt" in header and "hit" in header:
        trials = read_trials_csv(path)
        if unit is None:
            unit = "subject" if trials["subject"].nunique() > 1 else "location"
        logger.info("%s: %d raw trials, summarised per %s", path, len(trials), unit)
        return summarise_trials(trials, unit=unit, source=str(path))
    if unit is not None:
        logger.warning("%s: per-unit summary file; unit=%r ignored", path, unit)
    return read_summary_csv(path)

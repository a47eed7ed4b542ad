"""Import, tabulate and analyse gaze-HMI reach-and-grasp results (thesis chapter 6, Tables 6.2-6.11).

Conventions
-----------
* A *unit* is a subject (per-subject results, Table 6.10) or an object location (per-location results of one
  subject, Tables 6.2-6.4, 6.8). A *condition* is what was compared (filter, velocity profile, control strategy).
* Hit rates are stored as proportions ``hit_rate`` in [0, 1] (the thesis ANOVA tables use proportions) and as
  percentages ``hit_pct`` for the thesis-style tables. Times are in seconds (``time_s``, ``mean_time_s``).
* Conditions and units keep their order of first appearance in the file.
* Missing cells (a unit without a value for a condition) are kept as NaN; :meth:`HmiResults.analyse` uses the
  complete-case units and reports every excluded unit with the reason.
* Errors in a file raise :class:`wamctl.errors.DataFormatError` whose message names the file, the 1-based data row
  (the header is not counted, nor are blank lines and ``#`` comment lines), the line number, and the column.

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
Unknown columns are an error (so that a misspelt column is not silently ignored).

Times of misses count: when trials are summarised, ``mean_time_s`` is the mean over all attempts with a recorded
``time_s``.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from wamctl.analysis.anova import (
    CompleteCases,
    OneWayAnova,
    PairwiseTests,
    RMAnova,
    complete_cases,
    jsonable,
    one_way_anova,
    pairwise_paired_t,
    rm_anova,
)
from wamctl.errors import DataFormatError

logger = logging.getLogger(__name__)

__all__ = [
    "TRIAL_COLUMNS",
    "SUMMARY_COLUMNS",
    "MEASURES",
    "HmiResults",
    "HmiAnalysis",
    "read_hmi_csv",
    "read_trials_csv",
    "read_summary_csv",
    "summarise_trials",
]

TRIAL_COLUMNS: tuple[str, ...] = ("subject", "condition", "location", "attempt", "hit", "time_s")
"""Required columns of a raw-trials CSV."""

SUMMARY_COLUMNS: tuple[str, ...] = ("subject", "location", "condition", "hits", "attempts", "hit_pct",
                                    "mean_time_s")
"""Columns a per-unit summary CSV may have (plus ``note``)."""

MEASURES: tuple[str, ...] = ("hit_rate", "hit_pct", "mean_time_s")
"""Per-unit measures: hit proportion, hit percentage, mean execution time in seconds."""

ANOVA_MEASURES: tuple[str, ...] = ("hit_rate", "mean_time_s")
"""Measures analysed by default (the thesis ANOVA tables use proportions and seconds)."""

_MISSING = {"", "-", "na", "n/a", "nan"}  # numeric cells; a text cell is missing only if empty
_TRUE = {"1", "true", "yes", "y"}
_FALSE = {"0", "false", "no", "n"}
_STATS_ROWS = ("Mean", "SD", "SEM", "n")


# ----------------------------------------------------------------------------------------------------------------
# CSV reading and cell validation
# ----------------------------------------------------------------------------------------------------------------


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


def summarise_trials(trials: pd.DataFrame, *, unit: str = "subject", source: str = "") -> HmiResults:
    """Per-unit summaries of raw trials.

    Parameters
    ----------
    trials : pandas.DataFrame
        As returned by :func:`read_trials_csv`.
    unit : {"subject", "location"}
        ``"subject"``: one value per subject and condition, pooled over locations (Table 6.10 layout).
        ``"location"``: one value per location and condition, pooled over subjects (Tables 6.2-6.4 layout; the
        thesis had one subject).
    source : str, optional
        Where the trials came from (carried into the result).

    Returns
    -------
    HmiResults
        ``hits`` and ``attempts`` counted, ``hit_rate = hits / attempts``, ``mean_time_s`` the mean of the recorded
        times of all attempts (hits and misses; NaN if none recorded).
    """
    if unit not in ("subject", "location"):
        raise ValueError(f"unit must be 'subject' or 'location', got {unit!r}")
    grouped = trials.groupby([unit, "condition"], sort=False)
    data = grouped.agg(hits=("hit", "sum"), attempts=("hit", "size"), mean_time_s=("time_s", "mean")).reset_index()
    data["hits"] = data["hits"].astype(float)
    data["attempts"] = data["attempts"].astype(float)
    data["hit_rate"] = data["hits"] / data["attempts"]
    data["hit_pct"] = 100.0 * data["hit_rate"]
    data = data[[unit, "condition", "hits", "attempts", "hit_rate", "hit_pct", "mean_time_s"]]
    return HmiResults(data=data, unit_kind=unit, measures=MEASURES, source=source)


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


# ----------------------------------------------------------------------------------------------------------------
# results, tables and analysis
# ----------------------------------------------------------------------------------------------------------------


def _frame_to_json(frame: pd.DataFrame) -> dict[str, Any]:
    split = frame.to_dict(orient="split")
    return jsonable({"index_name": frame.index.name, "index": split["index"], "columns": split["columns"],
                     "data": split["data"]})


@dataclass(frozen=True)
class HmiResults:
    """Per-unit HMI results in long format.

    Attributes
    ----------
    data : pandas.DataFrame
        One row per (unit, condition): columns ``<unit_kind>, condition, hits, attempts, hit_rate, hit_pct,
        mean_time_s`` (NaN where not available or missing).
    unit_kind : str
        ``"subject"`` or ``"location"``; also the name of the unit column.
    measures : tuple of str
        Measures present in the source, from :data:`MEASURES`.
    source : str
        File the results came from (may be empty).
    """

    data: pd.DataFrame
    unit_kind: str
    measures: tuple[str, ...] = MEASURES
    source: str = ""

    @property
    def conditions(self) -> tuple[str, ...]:
        """Conditions in order of first appearance."""
        return tuple(str(c) for c in pd.unique(self.data["condition"]))

    @property
    def units(self) -> tuple[str, ...]:
        """Units in order of first appearance."""
        return tuple(str(u) for u in pd.unique(self.data[self.unit_kind]))

    def _measure(self, measure: str) -> str:
        if measure not in self.measures:
            raise DataFormatError(f"{self.source or 'HMI results'}: measure {measure!r} not available "
                                  f"(have {list(self.measures)})")
        return measure

    def wide(self, measure: str) -> pd.DataFrame:
        """Units x conditions table of one measure (NaN for missing cells).

        Parameters
        ----------
        measure : str
            One of :attr:`measures`.

        Returns
        -------
        pandas.DataFrame
            Index: units (named after :attr:`unit_kind`); columns: conditions, both in input order.
        """
        self._measure(measure)
        wide = self.data.pivot(index=self.unit_kind, columns="condition", values=measure)
        wide = wide.reindex(index=list(self.units), columns=list(self.conditions)).astype(float)
        wide.columns.name = "condition"
        return wide

    def table(self, measure: str) -> pd.DataFrame:
        """Thesis-style table (Tables 6.2-6.4, 6.10): one row per unit, then ``Mean, SD, SEM, n`` rows.

        Parameters
        ----------
        measure : str
            E.g. ``"hit_pct"`` (as printed) or ``"mean_time_s"``.

        Returns
        -------
        pandas.DataFrame
            Statistics over the units *available* for each condition (as the thesis' Average row of Table 6.10,
            which includes subject 9 in E1 and E4). ``SD`` is the sample SD (ddof=1), ``SEM = SD / sqrt(n)``.

        Notes
        -----
        The thesis rows labelled "SEM" hold the sample SD (e.g. Table 6.2, no filtering: printed 11.64, SD of the
        eight locations 11.65, SEM 4.12).
        """
        wide = self.wide(measure)
        stats = self._column_stats(wide)
        out = pd.concat([wide, stats.loc[["mean", "sd", "sem", "n"]].set_axis(list(_STATS_ROWS))])
        out.index.name = self.unit_kind
        return out

    @staticmethod
    def _column_stats(wide: pd.DataFrame) -> pd.DataFrame:
        n = wide.notna().sum()
        sd = wide.std(ddof=1)
        return pd.DataFrame({
            "n": n.astype(float), "mean": wide.mean(), "sd": sd, "sem": sd / np.sqrt(n),
            "median": wide.median(), "q1": wide.quantile(0.25), "q3": wide.quantile(0.75),
            "min": wide.min(), "max": wide.max(),
        }).T

    def condition_stats(self, measure: str, *, complete: bool = False,
                        measures: Sequence[str] | None = None) -> pd.DataFrame:
        """Per-condition n, mean, SD, SEM, median, quartiles, min, max.

        Parameters
        ----------
        measure : str
            Measure to describe.
        complete : bool, optional
            If True, only the complete-case units (complete in every measure of ``measures``).
        measures : sequence of str, optional
            Measures that define complete cases; default the available ones of ``("hit_rate", "mean_time_s")``.

        Returns
        -------
        pandas.DataFrame
            Index: conditions; columns ``n, mean, sd, sem, median, q1, q3, min, max``. With ``n``, ``mean`` and
            ``sd`` it is also the input of :func:`~wamctl.analysis.anova.one_way_anova_from_summary`.
        """
        wide = self.wide(measure)
        if complete:
            wide = wide.loc[list(self.complete_cases(measures).units)]
        out = self._column_stats(wide).T
        out.index.name = "condition"
        return out

    def complete_cases(self, measures: Sequence[str] | None = None) -> CompleteCases:
        """Units with a value of every measure in every condition, and the excluded ones with the reason.

        Parameters
        ----------
        measures : sequence of str, optional
            Default: the available ones of ``("hit_rate", "mean_time_s")``.

        Returns
        -------
        CompleteCases
        """
        measures = self._default_measures(measures)
        return complete_cases(self.data, unit=self.unit_kind, condition="condition", values=measures,
                              levels=self.conditions)

    def _default_measures(self, measures: Sequence[str] | None) -> tuple[str, ...]:
        if measures is None:
            measures = [m for m in ANOVA_MEASURES if m in self.measures]
        return tuple(self._measure(m) for m in measures)

    def anova_groups(self, measure: str, *, measures: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Raw one-way ANOVA input: condition -> values of the complete-case units.

        Parameters
        ----------
        measure : str
            Measure to analyse.
        measures : sequence of str, optional
            Measures that define complete cases (see :meth:`complete_cases`).

        Returns
        -------
        dict of str to numpy.ndarray
        """
        cc = self.complete_cases(measures)
        wide = self.wide(measure).loc[list(cc.units)]
        return {c: wide[c].to_numpy(float) for c in self.conditions}

    def analyse(self, measures: Sequence[str] | None = None, *, repeated: bool | None = None) -> HmiAnalysis:
        """One-way ANOVA (and repeated-measures ANOVA with pairwise tests) on the complete-case units.

        Parameters
        ----------
        measures : sequence of str, optional
            Measures to analyse; default the available ones of ``("hit_rate", "mean_time_s")``. Complete cases are
            taken over all of them together (as the thesis did: Table 6.11 uses the same 8 subjects for hits and
            time).
        repeated : bool, optional
            Also run the repeated-measures ANOVA, sphericity test and Holm-corrected paired t-tests. Default: True
            for per-subject results (every subject tried every condition), False for per-location results.

        Returns
        -------
        HmiAnalysis

        Raises
        ------
        DataFormatError
            Fewer than two complete units or two conditions remain.
        """
        measures = self._default_measures(measures)
        if repeated is None:
            repeated = self.unit_kind == "subject"
        cc = self.complete_cases(measures)
        name = self.source or "HMI results"
        if len(cc.units) < 2 or len(cc.levels) < 2:
            why = "; ".join(f"{e.unit}: {e.reason}" for e in cc.exclusions) or "none excluded"
            raise DataFormatError(f"{name}: need at least 2 complete {self.unit_kind}s and 2 conditions, have "
                                  f"{len(cc.units)} and {len(cc.levels)} (excluded: {why})")
        one_way: dict[str, OneWayAnova] = {}
        rm: dict[str, RMAnova] = {}
        pairwise: dict[str, PairwiseTests] = {}
        for m in measures:
            try:
                one_way[m] = one_way_anova(self.anova_groups(m, measures=measures), dv=m)
            except ValueError as exc:
                raise DataFormatError(f"{name}: one-way ANOVA of {m}: {exc}") from None
            if repeated:
                rm[m] = rm_anova(cc.data, dv=m, within="condition", subject=self.unit_kind)
                pairwise[m] = pairwise_paired_t(cc.data, dv=m, within="condition", subject=self.unit_kind)
        tables = {m: self.table(m) for m in self.measures if m != "hit_rate"}
        return HmiAnalysis(unit_kind=self.unit_kind, source=self.source, measures=measures, complete=cc,
                           one_way=one_way, rm=rm, pairwise=pairwise, tables=tables)


@dataclass(frozen=True)
class HmiAnalysis:
    """Everything a report needs from one set of HMI results.

    Attributes
    ----------
    unit_kind, source : str
        As in :class:`HmiResults`.
    measures : tuple of str
        Measures analysed.
    complete : CompleteCases
        Units kept and ``(unit, reason)`` exclusions.
    one_way, rm, pairwise : dict
        Per measure: :class:`~wamctl.analysis.anova.OneWayAnova`, :class:`~wamctl.analysis.anova.RMAnova` and
        :class:`~wamctl.analysis.anova.PairwiseTests` (the last two empty unless repeated measures were run).
    tables : dict of str to pandas.DataFrame
        Thesis-style tables (:meth:`HmiResults.table`) of ``hit_pct`` and ``mean_time_s``, available cases.
    """

    unit_kind: str
    source: str
    measures: tuple[str, ...]
    complete: CompleteCases
    one_way: dict[str, OneWayAnova] = field(default_factory=dict)
    rm: dict[str, RMAnova] = field(default_factory=dict)
    pairwise: dict[str, PairwiseTests] = field(default_factory=dict)
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)

    @property
    def exclusions(self) -> tuple:
        """``(unit, reason)`` of every excluded unit."""
        return self.complete.exclusions

    def to_pandas(self) -> dict[str, pd.DataFrame]:
        """All tables as data frames, keyed ``table_<measure>``, ``anova_<measure>``, ``rm_anova_<measure>``,
        ``pairwise_<measure>`` and ``exclusions``."""
        out: dict[str, pd.DataFrame] = {f"table_{m}": t for m, t in self.tables.items()}
        out.update({f"anova_{m}": a.to_pandas() for m, a in self.one_way.items()})
        out.update({f"rm_anova_{m}": a.to_pandas() for m, a in self.rm.items()})
        out.update({f"pairwise_{m}": a.to_pandas() for m, a in self.pairwise.items()})
        out["exclusions"] = self.complete.to_pandas()
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict carrying every number of every table."""
        return jsonable({
            "kind": "hmi_analysis", "unit_kind": self.unit_kind, "source": self.source,
            "measures": list(self.measures), "complete_cases": self.complete.to_dict(),
            "tables": {m: _frame_to_json(t) for m, t in self.tables.items()},
            "one_way_anova": {m: a.to_dict() for m, a in self.one_way.items()},
            "rm_anova": {m: a.to_dict() for m, a in self.rm.items()},
            "pairwise": {m: a.to_dict() for m, a in self.pairwise.items()},
        })


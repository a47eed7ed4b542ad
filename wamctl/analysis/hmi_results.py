"""Tabulate and analyse gaze-HMI reach-and-grasp results (thesis chapter 6, Tables 6.2-6.11).

Reading and validating result files is :mod:`wamctl.analysis.hmi_csv`; this module holds the results once read
(:class:`HmiResults`), the per-unit summaries of raw trials (:func:`summarise_trials`) and the analysis a report
renders (:class:`HmiAnalysis`).

Conventions
-----------
* A *unit* is a subject (per-subject results, Table 6.10) or an object location (per-location results of one
  subject, Tables 6.2-6.4, 6.8). A *condition* is what was compared (filter, velocity profile, control strategy).
* Raw trials have one row per attempt, with the columns :data:`TRIAL_COLUMNS`.
* Hit rates are stored as proportions ``hit_rate`` in [0, 1] (the thesis ANOVA tables use proportions) and as
  percentages ``hit_pct`` for the thesis-style tables. Times are in seconds (``time_s``, ``mean_time_s``).
* Conditions and units keep their order of first appearance.
* Missing cells (a unit without a value for a condition) are kept as NaN; :meth:`HmiResults.analyse` uses the
  complete-case units and reports every excluded unit with the reason.
* Times of misses count: when trials are summarised, ``mean_time_s`` is the mean over all attempts with a recorded
  ``time_s``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from wamctl.analysis.anova.cells import CompleteCases, complete_cases
from wamctl.analysis.anova.oneway import OneWayAnova, one_way_anova
from wamctl.analysis.anova.posthoc import PairwiseTests, pairwise_paired_t
from wamctl.analysis.anova.repeated import RMAnova, rm_anova
from wamctl.analysis.anova.tables import jsonable
from wamctl.errors import DataFormatError

TRIAL_COLUMNS: tuple[str, ...] = ("subject", "condition", "location", "attempt", "hit", "time_s")
"""Columns of raw trials, one row per attempt (also the required columns of a raw-trials CSV)."""

MEASURES: tuple[str, ...] = ("hit_rate", "hit_pct", "mean_time_s")
"""Per-unit measures: hit proportion, hit percentage, mean execution time in seconds."""

ANOVA_MEASURES: tuple[str, ...] = ("hit_rate", "mean_time_s")
"""Measures analysed by default (the thesis ANOVA tables use proportions and seconds)."""

_STATS_ROWS = ("Mean", "SD", "SEM", "n")


def summarise_trials(trials: pd.DataFrame, *, unit: str = "subject", source: str = "") -> HmiResults:
    """Per-unit summaries of raw trials.

    Parameters
    ----------
    trials : pandas.DataFrame
        As returned by :func:`~wamctl.analysis.hmi_csv.read_trials_csv`.
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
            ``sd`` it is also the input of :func:`~wamctl.analysis.anova.oneway.one_way_anova_from_summary`.
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
        Per measure: :class:`~wamctl.analysis.anova.oneway.OneWayAnova`,
        :class:`~wamctl.analysis.anova.repeated.RMAnova` and :class:`~wamctl.analysis.anova.posthoc.PairwiseTests`
        (the last two empty unless repeated measures were run).
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

"""Analysis of variance for HMI results: one-way and repeated-measures ANOVA, pairwise tests, missing cells.

Pure library: no file I/O, no plotting, no printing.

Conventions
-----------
* A *unit* is what was measured repeatedly: a subject (thesis Table 6.10) or an object location (Tables 6.2-6.4,
  6.8). A *condition* is a level of the within factor (filter, velocity profile, control strategy).
* Values are analysed in the unit they are given in. The thesis ANOVA tables use hit *proportions* (0-1) and
  execution times in seconds; :mod:`wamctl.analysis.hmi_results` converts percentages to proportions.
* Long-format data frames have one row per (unit, condition); the column names are passed explicitly.
* Condition order is the order of first appearance, never alphabetical.
* Missing cells are never dropped silently: :func:`complete_cases` returns the complete-case subset and the list of
  excluded units with the reason. The ANOVA functions reject NaN.
* ``p`` values are uncorrected unless the name says otherwise (``p_gg``, ``p_hf``, ``p_holm``).
* Result objects are frozen dataclasses with ``to_pandas()`` (for rendering) and ``to_dict()`` (JSON-safe:
  plain floats, ints, strings; NaN becomes ``None``).

Libraries
---------
* One-way ANOVA from raw observations: F and p from :func:`scipy.stats.f_oneway`; the sums of squares (which
  scipy does not return) from their definitions.
* One-way ANOVA from per-group summaries (n, mean, SD or SEM): hand-written sums of squares,
  ``SS_between = sum n_i (m_i - m)^2`` and ``SS_within = sum (n_i - 1) s_i^2``, p from the F distribution
  (:func:`scipy.stats.f.sf`). With exact summaries this equals the raw form.
* Repeated-measures ANOVA, Mauchly's test, Greenhouse-Geisser / Huynh-Feldt epsilon and Holm-corrected paired
  t-tests: ``pingouin`` (imported lazily, it is slow to import). The corrected p values are computed here from the
  epsilon: ``p = F.sf(F, eps * df_effect, eps * df_error)``.
"""

from __future__ import annotations

import itertools
import logging
import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import pandas as pd
from scipy import stats

logger = logging.getLogger(__name__)

__all__ = [
    "AnovaRow",
    "OneWayAnova",
    "Sphericity",
    "RMAnova",
    "PairwiseComparison",
    "PairwiseTests",
    "Exclusion",
    "CompleteCases",
    "one_way_anova",
    "one_way_anova_from_summary",
    "rm_anova",
    "pairwise_paired_t",
    "complete_cases",
    "jsonable",
]


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------


def _num(x: Any) -> float | None:
    """Return ``x`` as a JSON-safe float (``None`` for NaN/None/inf)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def jsonable(x: Any) -> Any:
    """Convert numpy scalars, tuples and NaN to JSON-native values, recursively.

    Parameters
    ----------
    x : object
        Mapping, sequence, scalar (numpy or Python) or string.

    Returns
    -------
    object
        Same structure with dict keys as ``str``, sequences as ``list``, NaN/inf as ``None``; anything else
        unknown as ``str(x)``.
    """
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return _num(x)
    if x is None or isinstance(x, str):
        return x
    return str(x)


@contextmanager
def _quiet_pingouin() -> Iterator[Any]:
    """Import pingouin and silence its pandas-3 deprecation warnings (``inplace=`` in its own code)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*inplace keyword.*")
        warnings.filterwarnings("ignore", category=FutureWarning, module=r"pingouin.*")
        import pingouin

        yield pingouin


def _levels(series: pd.Series) -> tuple[str, ...]:
    return tuple(str(v) for v in pd.unique(series))


# ----------------------------------------------------------------------------------------------------------------
# one-way ANOVA
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AnovaRow:
    """One line of an ANOVA table.

    Attributes
    ----------
    source : str
        ``"Between Groups"``, ``"Within Groups"``, ``"Total"``, or for repeated measures the factor name,
        ``"Subjects"``, ``"Error"``, ``"Total"``.
    ss : float
        Sum of squares, in squared units of the dependent variable.
    df : int
        Degrees of freedom.
    ms : float or None
        Mean square ``ss / df`` (``None`` on the total line, as the thesis prints it).
    f : float or None
        F statistic (effect lines only).
    p : float or None
        Uncorrected p value (effect lines only).
    """

    source: str
    ss: float
    df: int
    ms: float | None = None
    f: float | None = None
    p: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict with keys ``source, ss, df, ms, F, p``."""
        return {"source": self.source, "ss": _num(self.ss), "df": int(self.df), "ms": _num(self.ms),
                "F": _num(self.f), "p": _num(self.p)}


def _rows_to_pandas(rows: Sequence[AnovaRow]) -> pd.DataFrame:
    frame = pd.DataFrame(
        {"SS": [r.ss for r in rows], "df": [r.df for r in rows],
         "MS": [np.nan if r.ms is None else r.ms for r in rows],
         "F": [np.nan if r.f is None else r.f for r in rows],
         "p": [np.nan if r.p is None else r.p for r in rows]},
        index=pd.Index([r.source for r in rows], name="source"),
    )
    return frame


@dataclass(frozen=True)
class OneWayAnova:
    """One-way (between-groups) ANOVA table, as printed in thesis Tables 6.5, 6.6, 6.9, 6.11.

    Attributes
    ----------
    dv : str
        Name of the dependent variable (e.g. ``"hit_rate"``, ``"mean_time_s"``).
    groups : tuple of str
        Group (condition) labels in input order.
    n : tuple of int
        Observations per group.
    means, sds : tuple of float
        Per-group mean and sample standard deviation (ddof=1; NaN if n == 1).
    between, within, total : AnovaRow
        The three lines of the table.
    input_form : str
        ``"raw"`` (observations per group) or ``"summary"`` (n, mean, SD/SEM per group).
    """

    dv: str
    groups: tuple[str, ...]
    n: tuple[int, ...]
    means: tuple[float, ...]
    sds: tuple[float, ...]
    between: AnovaRow
    within: AnovaRow
    total: AnovaRow
    input_form: str

    @property
    def f(self) -> float:
        """F statistic (between / within mean squares)."""
        return float(self.between.f)  # type: ignore[arg-type]

    @property
    def p(self) -> float:
        """p value of the F test."""
        return float(self.between.p)  # type: ignore[arg-type]

    @property
    def df(self) -> tuple[int, int]:
        """(between df, within df)."""
        return (self.between.df, self.within.df)

    def apa(self, f_digits: int = 2, p_digits: int = 4) -> str:
        """Format as in the thesis text, e.g. ``"F(5, 42) = 2.86, p = 0.0262"``."""
        return f"F({self.df[0]}, {self.df[1]}) = {self.f:.{f_digits}f}, p = {self.p:.{p_digits}f}"

    def to_pandas(self) -> pd.DataFrame:
        """ANOVA table: index ``Between Groups, Within Groups, Total``; columns ``SS, df, MS, F, p``."""
        return _rows_to_pandas([self.between, self.within, self.total])

    def group_stats(self) -> pd.DataFrame:
        """Per-group n, mean and SD (index: group)."""
        return pd.DataFrame({"n": self.n, "mean": self.means, "sd": self.sds},
                            index=pd.Index(self.groups, name="group"))

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict carrying every number of the table and the group statistics."""
        return jsonable({
            "kind": "one_way_anova", "dv": self.dv, "input_form": self.input_form,
            "F": self.f, "df_between": self.df[0], "df_within": self.df[1], "p": self.p,
            "table": [r.to_dict() for r in (self.between, self.within, self.total)],
            "groups": [{"group": g, "n": n, "mean": m, "sd": s}
                       for g, n, m, s in zip(self.groups, self.n, self.means, self.sds)],
        })


def _one_way_table(dv: str, groups: Sequence[str], n: np.ndarray, means: np.ndarray, sds: np.ndarray,
                   ss_between: float, ss_within: float, f: float, p: float, input_form: str) -> OneWayAnova:
    k = len(groups)
    n_total = int(n.sum())
    df_b, df_w = k - 1, n_total - k
    between = AnovaRow("Between Groups", float(ss_between), df_b, float(ss_between) / df_b, float(f), float(p))
    within = AnovaRow("Within Groups", float(ss_within), df_w, float(ss_within) / df_w)
    total = AnovaRow("Total", float(ss_between + ss_within), n_total - 1)
    return OneWayAnova(dv=dv, groups=tuple(str(g) for g in groups), n=tuple(int(v) for v in n),
                       means=tuple(float(v) for v in means), sds=tuple(float(v) for v in sds),
                       between=between, within=within, total=total, input_form=input_form)


def _check_shape(k: int, n_total: int) -> None:
    if k < 2:
        raise ValueError(f"one-way ANOVA needs at least 2 groups, got {k}")
    if n_total - k < 1:
        raise ValueError(f"one-way ANOVA needs more observations ({n_total}) than groups ({k})")


def one_way_anova(groups: Mapping[str, Sequence[float] | np.ndarray], *, dv: str = "y") -> OneWayAnova:
    """One-way ANOVA from raw observations per group.

    Parameters
    ----------
    groups : mapping of str to array_like
        Group label -> observations (one value per unit, e.g. the hit proportion of each location). Groups may have
        different sizes. NaN is rejected: decide about missing cells first (:func:`complete_cases`).
    dv : str, optional
        Name of the dependent variable, carried into the result.

    Returns
    -------
    OneWayAnova
        F and p from :func:`scipy.stats.f_oneway`; SS from their definitions.

    Raises
    ------
    ValueError
        Fewer than 2 groups, an empty group, NaN values, or no within-group degrees of freedom.
    """
    labels = [str(g) for g in groups]
    arrays = [np.asarray(v, dtype=float).ravel() for v in groups.values()]
    for label, a in zip(labels, arrays):
        if a.size == 0:
            raise ValueError(f"group {label!r} has no observations")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"group {label!r} contains NaN/inf; resolve missing cells first (complete_cases)")
    n = np.array([a.size for a in arrays])
    _check_shape(len(arrays), int(n.sum()))
    means = np.array([a.mean() for a in arrays])
    sds = np.array([a.std(ddof=1) if a.size > 1 else np.nan for a in arrays])
    grand = np.concatenate(arrays).mean()
    ss_between = float(np.sum(n * (means - grand) ** 2))
    ss_within = float(sum(np.sum((a - a.mean()) ** 2) for a in arrays))
    res = stats.f_oneway(*arrays)
    f, p = float(res.statistic), float(res.pvalue)
    df_b, df_w = len(arrays) - 1, int(n.sum()) - len(arrays)
    if ss_within > 0 and not math.isclose(f, (ss_between / df_b) / (ss_within / df_w), rel_tol=1e-8, abs_tol=1e-12):
        raise RuntimeError("scipy F disagrees with the sums of squares")  # programming error, never user data
    return _one_way_table(dv, labels, n, means, sds, ss_between, ss_within, f, p, "raw")


def one_way_anova_from_summary(summary: pd.DataFrame, *, dv: str = "y") -> OneWayAnova:
    """One-way ANOVA from per-group summaries (n, mean, and SD or SEM).

    Parameters
    ----------
    summary : pandas.DataFrame
        Index: group labels (order kept). Columns ``n`` and ``mean``, and ``sd`` (sample SD, ddof=1) or ``sem``
        (``sd / sqrt(n)``). If both are given, ``sd`` is used.
    dv : str, optional
        Name of the dependent variable.

    Returns
    -------
    OneWayAnova
        ``input_form == "summary"``. Sums of squares are hand-written (scipy has no summary-statistics ANOVA):
        ``SS_between = sum n_i (m_i - m)^2`` with ``m = sum n_i m_i / N`` and ``SS_within = sum (n_i - 1) s_i^2``;
        ``p = scipy.stats.f.sf(F, k - 1, N - k)``.

    Notes
    -----
    The result is only as precise as the summaries: printed means and SDs rounded to 3-4 digits give F to about
    2 digits. The thesis' rows labelled "SEM" are in fact sample SDs; pass them as ``sd``.
    """
    missing = {"n", "mean"} - set(summary.columns)
    if missing:
        raise ValueError(f"summary is missing column(s) {sorted(missing)}")
    n = summary["n"].to_numpy(dtype=float)
    means = summary["mean"].to_numpy(dtype=float)
    if "sd" in summary.columns:
        sds = summary["sd"].to_numpy(dtype=float)
    elif "sem" in summary.columns:
        sds = summary["sem"].to_numpy(dtype=float) * np.sqrt(n)
    else:
        raise ValueError("summary needs a 'sd' or a 'sem' column")
    if np.any(n < 1) or np.any(n != np.round(n)):
        raise ValueError("summary column 'n' must hold positive integers")
    if not np.all(np.isfinite(means)):
        raise ValueError("summary column 'mean' contains NaN")
    bad_sd = ~np.isfinite(sds) & (n > 1)
    if np.any(bad_sd):
        raise ValueError(f"summary SD/SEM missing for group(s) {list(summary.index[bad_sd])}")
    sds_for_ss = np.where(n > 1, sds, 0.0)
    _check_shape(len(n), int(n.sum()))
    grand = float(np.sum(n * means) / n.sum())
    ss_between = float(np.sum(n * (means - grand) ** 2))
    ss_within = float(np.sum((n - 1) * sds_for_ss ** 2))
    k, n_total = len(n), int(n.sum())
    f = (ss_between / (k - 1)) / (ss_within / (n_total - k)) if ss_within > 0 else math.inf
    p = float(stats.f.sf(f, k - 1, n_total - k))
    return _one_way_table(dv, list(summary.index), n.astype(int), means, np.where(n > 1, sds, np.nan),
                          ss_between, ss_within, f, p, "summary")


# ----------------------------------------------------------------------------------------------------------------
# missing cells
# ----------------------------------------------------------------------------------------------------------------


class Exclusion(NamedTuple):
    """A unit left out of an analysis: ``(unit, reason)``."""

    unit: str
    reason: str


@dataclass(frozen=True)
class CompleteCases:
    """Complete-case subset of long-format data and the units excluded from it.

    Attributes
    ----------
    data : pandas.DataFrame
        Rows of the units that have a finite value of every requested column in every condition.
    exclusions : tuple of Exclusion
        ``(unit, reason)`` for every unit left out, in input order.
    units : tuple of str
        Units kept, in input order.
    levels : tuple of str
        Conditions required of every unit.
    values : tuple of str
        Columns checked.
    """

    data: pd.DataFrame
    exclusions: tuple[Exclusion, ...]
    units: tuple[str, ...]
    levels: tuple[str, ...]
    values: tuple[str, ...]

    def to_pandas(self) -> pd.DataFrame:
        """Exclusions as a table with columns ``unit, reason``."""
        return pd.DataFrame(list(self.exclusions), columns=["unit", "reason"])

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict: kept units, levels, checked columns and exclusions."""
        return jsonable({"units_kept": list(self.units), "levels": list(self.levels), "values": list(self.values),
                          "exclusions": [{"unit": e.unit, "reason": e.reason} for e in self.exclusions]})


def complete_cases(data: pd.DataFrame, *, unit: str, condition: str, values: Sequence[str],
                   levels: Sequence[str] | None = None) -> CompleteCases:
    """Keep the units with a value in every condition; report the others.

    Parameters
    ----------
    data : pandas.DataFrame
        Long format, at most one row per (unit, condition).
    unit, condition : str
        Column names of the unit (subject or location) and the condition.
    values : sequence of str
        Columns that must be finite (e.g. ``["hit_rate", "mean_time_s"]``).
    levels : sequence of str, optional
        Conditions every unit must have; default: every condition present in ``data``.

    Returns
    -------
    CompleteCases
        The subset (row order kept) and ``(unit, reason)`` exclusions such as
        ``("9", "missing E2: no data; E3: no data")``.

    Raises
    ------
    ValueError
        A column is absent or a (unit, condition) pair occurs twice.
    """
    values = tuple(values)
    absent = [c for c in (unit, condition, *values) if c not in data.columns]
    if absent:
        raise ValueError(f"data has no column(s) {absent}")
    frame = data.copy()
    frame[unit] = frame[unit].astype(str)
    frame[condition] = frame[condition].astype(str)
    dup = frame.duplicated([unit, condition], keep=False)
    if dup.any():
        pairs = sorted({(u, c) for u, c in frame.loc[dup, [unit, condition]].itertuples(index=False)})
        raise ValueError(f"duplicate (unit, condition) rows: {pairs}")
    lv = tuple(str(v) for v in levels) if levels is not None else _levels(frame[condition])
    exclusions: list[Exclusion] = []
    kept: list[str] = []
    for u in _levels(frame[unit]):
        rows = frame[frame[unit] == u].set_index(condition)
        problems: list[str] = []
        for c in lv:
            if c not in rows.index:
                problems.append(f"{c}: no data")
                continue
            bad = [v for v in values if not np.isfinite(pd.to_numeric(rows.at[c, v], errors="coerce"))]
            if len(bad) == len(values) and len(values) > 1:
                problems.append(f"{c}: no data")
            elif bad:
                problems.append(f"{c}: no {', '.join(bad)}")
        if problems:
            exclusions.append(Exclusion(u, "missing " + "; ".join(problems)))
        else:
            kept.append(u)
    subset = frame[frame[unit].isin(kept) & frame[condition].isin(lv)].reset_index(drop=True)
    for e in exclusions:
        logger.info("excluded %s %s: %s", unit, e.unit, e.reason)
    return CompleteCases(data=subset, exclusions=tuple(exclusions), units=tuple(kept), levels=lv, values=values)


def _require_complete(data: pd.DataFrame, dv: str, within: str, subject: str) -> tuple[pd.DataFrame, tuple[str, ...]]:
    cc = complete_cases(data, unit=subject, condition=within, values=[dv])
    if cc.exclusions:
        raise ValueError("repeated-measures analysis needs complete data; incomplete units: "
                         + "; ".join(f"{e.unit} ({e.reason})" for e in cc.exclusions)
                         + ". Use complete_cases() first.")
    if len(cc.units) < 2:
        raise ValueError(f"repeated-measures analysis needs at least 2 units, got {len(cc.units)}")
    if len(cc.levels) < 2:
        raise ValueError(f"repeated-measures analysis needs at least 2 conditions, got {len(cc.levels)}")
    out = cc.data[[subject, within, dv]].copy()
    out[dv] = out[dv].astype(float)
    return out, cc.levels


# ----------------------------------------------------------------------------------------------------------------
# repeated-measures ANOVA
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Sphericity:
    """Mauchly's test and the sphericity corrections of a one-factor repeated-measures ANOVA.

    Attributes
    ----------
    w, chi2 : float
        Mauchly's W and its chi-square approximation.
    dof : int
        Degrees of freedom of the chi-square, ``k (k - 1) / 2 - 1``.
    p : float
        p value of Mauchly's test (small p: sphericity violated); pingouin's second-order chi-square approximation,
        the same as R's ``mauchly.test``.
    eps_gg, eps_hf, eps_lb : float
        Greenhouse-Geisser, Huynh-Feldt (capped at 1) and lower-bound (``1 / (k - 1)``) epsilon.
    p_gg, p_hf : float
        p value of the F test with both df multiplied by the epsilon.
    df_gg, df_hf : tuple of float
        The corrected (effect, error) degrees of freedom.
    """

    w: float
    chi2: float
    dof: int
    p: float
    eps_gg: float
    eps_hf: float
    eps_lb: float
    p_gg: float
    p_hf: float
    df_gg: tuple[float, float]
    df_hf: tuple[float, float]

    def assumed(self, alpha: float = 0.05) -> bool:
        """True if Mauchly's test does not reject sphericity at ``alpha``."""
        return not (self.p < alpha)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict of every number."""
        return jsonable({"mauchly_W": self.w, "chi2": self.chi2, "dof": self.dof, "p": self.p,
                          "sphericity_assumed": self.assumed(), "eps_gg": self.eps_gg, "eps_hf": self.eps_hf,
                          "eps_lb": self.eps_lb, "p_gg": self.p_gg, "p_hf": self.p_hf,
                          "df_gg": list(self.df_gg), "df_hf": list(self.df_hf)})


@dataclass(frozen=True)
class RMAnova:
    """One-factor repeated-measures ANOVA (units x condition) with sphericity test and corrections.

    Attributes
    ----------
    dv, within, subject : str
        Column names used.
    levels : tuple of str
        Conditions, in input order.
    units : tuple of str
        Units (subjects) analysed.
    effect, subjects, error, total : AnovaRow
        Table lines. ``effect`` carries F and the uncorrected p; ``subjects`` is the between-units variation
        removed from the error term; ``total = effect + subjects + error``.
    eta2_generalized : float
        Generalised eta squared (pingouin ``ng2``).
    eta2_partial : float
        ``SS_effect / (SS_effect + SS_error)``.
    sphericity : Sphericity
        Mauchly's test, epsilons and corrected p values.
    """

    dv: str
    within: str
    subject: str
    levels: tuple[str, ...]
    units: tuple[str, ...]
    effect: AnovaRow
    subjects: AnovaRow
    error: AnovaRow
    total: AnovaRow
    eta2_generalized: float
    eta2_partial: float
    sphericity: Sphericity

    @property
    def f(self) -> float:
        """F statistic of the condition effect."""
        return float(self.effect.f)  # type: ignore[arg-type]

    @property
    def p(self) -> float:
        """Uncorrected p value."""
        return float(self.effect.p)  # type: ignore[arg-type]

    @property
    def df(self) -> tuple[int, int]:
        """(effect df, error df), uncorrected."""
        return (self.effect.df, self.error.df)

    def apa(self, f_digits: int = 2, p_digits: int = 3) -> str:
        """E.g. ``"F(5, 35) = 3.04, p = 0.022 (GG eps = 0.643, p = 0.047; Mauchly W = 0.135, p = 0.779)"``."""
        s = self.sphericity
        return (f"F({self.df[0]}, {self.df[1]}) = {self.f:.{f_digits}f}, p = {self.p:.{p_digits}f} "
                f"(GG eps = {s.eps_gg:.3f}, p = {s.p_gg:.{p_digits}f}; Mauchly W = {s.w:.3f}, p = {s.p:.3f})")

    def to_pandas(self) -> pd.DataFrame:
        """Table with index ``<within>, Subjects, Error, Total`` and columns ``SS, df, MS, F, p, p_GG, p_HF``."""
        frame = _rows_to_pandas([self.effect, self.subjects, self.error, self.total])
        frame["p_GG"] = [self.sphericity.p_gg, np.nan, np.nan, np.nan]
        frame["p_HF"] = [self.sphericity.p_hf, np.nan, np.nan, np.nan]
        return frame

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict of every number, including the sphericity block."""
        return jsonable({
            "kind": "rm_anova", "dv": self.dv, "within": self.within, "subject": self.subject,
            "levels": list(self.levels), "units": list(self.units), "n_units": len(self.units),
            "F": self.f, "df_effect": self.df[0], "df_error": self.df[1], "p_unc": self.p,
            "eta2_generalized": self.eta2_generalized, "eta2_partial": self.eta2_partial,
            "table": [r.to_dict() for r in (self.effect, self.subjects, self.error, self.total)],
            "sphericity": self.sphericity.to_dict(),
        })


def rm_anova(data: pd.DataFrame, *, dv: str, within: str, subject: str) -> RMAnova:
    """One-factor repeated-measures ANOVA with Mauchly's test and Greenhouse-Geisser / Huynh-Feldt corrections.

    Parameters
    ----------
    data : pandas.DataFrame
        Long format, exactly one row per (subject, condition), no missing cells (see :func:`complete_cases`).
    dv, within, subject : str
        Column names of the dependent variable, the condition and the unit.

    Returns
    -------
    RMAnova

    Raises
    ------
    ValueError
        Missing cells, duplicates, fewer than 2 units or conditions.

    Notes
    -----
    The F test, generalised eta squared, Mauchly's W and the epsilons come from pingouin (``rm_anova``,
    ``sphericity``, ``epsilon``). The subjects and total lines are computed here from their definitions. With two
    conditions sphericity holds trivially (W = 1, p = 1, epsilon = 1). Mauchly's test needs more units than
    conditions; otherwise W is reported as NaN.
    """
    frame, levels = _require_complete(data, dv, within, subject)
    units = _levels(frame[subject])
    k, n = len(levels), len(units)
    with _quiet_pingouin() as pg:
        aov = pg.rm_anova(data=frame, dv=dv, within=within, subject=subject, detailed=True, correction=False)
        if k > 2:
            spher = pg.sphericity(frame, dv=dv, within=within, subject=subject)
            w, chi2, dof, p_mauchly = float(spher[1]), float(spher[2]), int(spher[3]), float(spher[4])
        else:
            w, chi2, dof, p_mauchly = 1.0, 0.0, 0, 1.0
        eps_gg = float(pg.epsilon(frame, dv=dv, within=within, subject=subject, correction="gg"))
        eps_hf = float(pg.epsilon(frame, dv=dv, within=within, subject=subject, correction="hf"))
    row_effect = aov.iloc[0]
    row_error = aov.iloc[1]
    ss_eff, df_eff = float(row_effect["SS"]), int(row_effect["DF"])
    ss_err, df_err = float(row_error["SS"]), int(row_error["DF"])
    f, p = float(row_effect["F"]), float(row_effect["p_unc"])
    y = frame[dv].to_numpy(float)
    grand = y.mean()
    ss_total = float(np.sum((y - grand) ** 2))
    unit_means = frame.groupby(subject, sort=False)[dv].mean().to_numpy(float)
    ss_subj = float(k * np.sum((unit_means - grand) ** 2))
    eps_lb = 1.0 / (k - 1)
    p_gg = float(stats.f.sf(f, eps_gg * df_eff, eps_gg * df_err))
    p_hf = float(stats.f.sf(f, eps_hf * df_eff, eps_hf * df_err))
    sph = Sphericity(w=w, chi2=chi2, dof=dof, p=p_mauchly, eps_gg=eps_gg, eps_hf=eps_hf, eps_lb=eps_lb,
                     p_gg=p_gg, p_hf=p_hf, df_gg=(eps_gg * df_eff, eps_gg * df_err),
                     df_hf=(eps_hf * df_eff, eps_hf * df_err))
    result = RMAnova(
        dv=dv, within=within, subject=subject, levels=levels, units=units,
        effect=AnovaRow(within, ss_eff, df_eff, ss_eff / df_eff, f, p),
        subjects=AnovaRow("Subjects", ss_subj, n - 1, ss_subj / (n - 1)),
        error=AnovaRow("Error", ss_err, df_err, ss_err / df_err),
        total=AnovaRow("Total", ss_total, n * k - 1),
        eta2_generalized=float(row_effect.get("ng2", np.nan)),
        eta2_partial=ss_eff / (ss_eff + ss_err) if (ss_eff + ss_err) > 0 else math.nan,
        sphericity=sph,
    )
    logger.debug("rm_anova %s: %s", dv, result.apa())
    return result


# ----------------------------------------------------------------------------------------------------------------
# pairwise comparisons
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PairwiseComparison:
    """Paired t-test between two conditions.

    Attributes
    ----------
    a, b : str
        Conditions compared (``a`` before ``b`` in input order).
    n : int
        Number of pairs (units).
    mean_diff : float
        Mean of ``a - b``.
    t : float
        t statistic of ``a - b``.
    dof : float
        Degrees of freedom (``n - 1``).
    p_unc, p_holm : float
        Uncorrected and Holm-corrected two-sided p values.
    hedges_g : float
        Hedges' g effect size (pingouin).
    """

    a: str
    b: str
    n: int
    mean_diff: float
    t: float
    dof: float
    p_unc: float
    p_holm: float
    hedges_g: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict."""
        return jsonable(self.__dict__)


@dataclass(frozen=True)
class PairwiseTests:
    """All pairwise paired t-tests of one dependent variable, Holm-corrected over the family.

    Attributes
    ----------
    dv : str
        Dependent variable.
    comparisons : tuple of PairwiseComparison
        In input order of the conditions: (1, 2), (1, 3), ..., (k - 1, k).
    """

    dv: str
    comparisons: tuple[PairwiseComparison, ...] = field(default_factory=tuple)

    def to_pandas(self) -> pd.DataFrame:
        """One row per pair, columns as the :class:`PairwiseComparison` attributes."""
        return pd.DataFrame([c.__dict__ for c in self.comparisons])

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict."""
        return {"kind": "pairwise_paired_t", "dv": self.dv, "p_adjust": "holm",
                "comparisons": [c.to_dict() for c in self.comparisons]}


def pairwise_paired_t(data: pd.DataFrame, *, dv: str, within: str, subject: str) -> PairwiseTests:
    """Holm-corrected pairwise paired t-tests between all conditions.

    Parameters
    ----------
    data : pandas.DataFrame
        Long format, complete (see :func:`complete_cases`).
    dv, within, subject : str
        Column names.

    Returns
    -------
    PairwiseTests
        Computed with ``pingouin.pairwise_tests(..., padjust="holm")``; the pairs are reordered (and the sign of t
        flipped where needed) so that ``a`` precedes ``b`` in input order.
    """
    frame, levels = _require_complete(data, dv, within, subject)
    with _quiet_pingouin() as pg:
        table = pg.pairwise_tests(data=frame, dv=dv, within=within, subject=subject, padjust="holm",
                                  parametric=True)
    has_corr = "p_corr" in table.columns  # pingouin leaves it out for a single comparison (Holm = identity)
    by_pair = {(str(r["A"]), str(r["B"])): r for _, r in table.iterrows()}
    wide = frame.pivot(index=subject, columns=within, values=dv)
    out = []
    for a, b in itertools.combinations(levels, 2):
        if (a, b) in by_pair:
            r, sign = by_pair[(a, b)], 1.0
        else:
            r, sign = by_pair[(b, a)], -1.0
        diff = (wide[a] - wide[b]).to_numpy(float)
        out.append(PairwiseComparison(a=a, b=b, n=int(diff.size), mean_diff=float(diff.mean()),
                                      t=sign * float(r["T"]), dof=float(r["dof"]), p_unc=float(r["p_unc"]),
                                      p_holm=float(r["p_corr"]) if has_corr else float(r["p_unc"]),
                                      hedges_g=sign * float(r["hedges"])))
    return PairwiseTests(dv=dv, comparisons=tuple(out))

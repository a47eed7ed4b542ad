"""One-way (between-groups) ANOVA, from raw observations per group or from per-group summaries."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from wamctl.analysis.anova.tables import AnovaRow, jsonable, rows_to_pandas


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
        return rows_to_pandas([self.between, self.within, self.total])

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


def _ss_between(n: np.ndarray, means: np.ndarray, grand: float) -> float:
    """``SS_between = sum n_i (m_i - m)^2``, from group sizes, group means and the grand mean."""
    return float(np.sum(n * (means - grand) ** 2))


def _f_ratio(ss_between: float, ss_within: float, df_between: int, df_within: int) -> float:
    """F statistic: between over within mean square."""
    return (ss_between / df_between) / (ss_within / df_within)


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
        different sizes. NaN is rejected: decide about missing cells first
        (:func:`~wamctl.analysis.anova.cells.complete_cases`).
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
    ss_between = _ss_between(n, means, grand)
    ss_within = float(sum(np.sum((a - a.mean()) ** 2) for a in arrays))
    res = stats.f_oneway(*arrays)
    f, p = float(res.statistic), float(res.pvalue)
    df_b, df_w = len(arrays) - 1, int(n.sum()) - len(arrays)
    if ss_within > 0 and not math.isclose(f, _f_ratio(ss_between, ss_within, df_b, df_w), rel_tol=1e-8, abs_tol=1e-12):
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
    ss_between = _ss_between(n, means, grand)
    ss_within = float(np.sum((n - 1) * sds_for_ss ** 2))
    k, n_total = len(n), int(n.sum())
    f = _f_ratio(ss_between, ss_within, k - 1, n_total - k) if ss_within > 0 else math.inf
    p = float(stats.f.sf(f, k - 1, n_total - k))
    return _one_way_table(dv, list(summary.index), n.astype(int), means, np.where(n > 1, sds, np.nan),
                          ss_between, ss_within, f, p, "summary")


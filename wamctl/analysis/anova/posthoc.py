"""Post-hoc comparisons: Holm-corrected pairwise paired t-tests between the conditions of repeated measures."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from wamctl.analysis.anova.cells import require_complete
from wamctl.analysis.anova.tables import jsonable, quiet_pingouin


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
        Long format, complete (see :func:`~wamctl.analysis.anova.cells.complete_cases`).
    dv, within, subject : str
        Column names.

    Returns
    -------
    PairwiseTests
        Computed with ``pingouin.pairwise_tests(..., padjust="holm")``; the pairs are reordered (and the sign of t
        flipped where needed) so that ``a`` precedes ``b`` in input order.
    """
    frame, levels = require_complete(data, dv, within, subject)
    with quiet_pingouin() as pg:
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

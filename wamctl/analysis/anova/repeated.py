"""One-factor repeated-measures ANOVA with Mauchly's test and the Greenhouse-Geisser / Huynh-Feldt corrections."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from wamctl.analysis.anova.cells import require_complete
from wamctl.analysis.anova.tables import AnovaRow, jsonable, levels_in_order, quiet_pingouin, rows_to_pandas

logger = logging.getLogger(__name__)


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
        frame = rows_to_pandas([self.effect, self.subjects, self.error, self.total])
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


def _corrected(f: float, eps: float, df_effect: int, df_error: int) -> tuple[float, tuple[float, float]]:
    """p value and (effect, error) degrees of freedom of the F test with both df multiplied by ``eps``."""
    df = (eps * df_effect, eps * df_error)
    return float(stats.f.sf(f, df[0], df[1])), df


def rm_anova(data: pd.DataFrame, *, dv: str, within: str, subject: str) -> RMAnova:
    """One-factor repeated-measures ANOVA with Mauchly's test and Greenhouse-Geisser / Huynh-Feldt corrections.

    Parameters
    ----------
    data : pandas.DataFrame
        Long format, exactly one row per (subject, condition), no missing cells (see
        :func:`~wamctl.analysis.anova.cells.complete_cases`).
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
    frame, levels = require_complete(data, dv, within, subject)
    units = levels_in_order(frame[subject])
    k, n = len(levels), len(units)
    with quiet_pingouin() as pg:
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
    p_gg, df_gg = _corrected(f, eps_gg, df_eff, df_err)
    p_hf, df_hf = _corrected(f, eps_hf, df_eff, df_err)
    sph = Sphericity(w=w, chi2=chi2, dof=dof, p=p_mauchly, eps_gg=eps_gg, eps_hf=eps_hf, eps_lb=eps_lb,
                     p_gg=p_gg, p_hf=p_hf, df_gg=df_gg, df_hf=df_hf)
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

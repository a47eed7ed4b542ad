"""Missing cells: the complete-case subset of long-format data and the units left out, with the reason."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from wamctl.analysis.anova.tables import jsonable, levels_in_order

logger = logging.getLogger(__name__)


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
    lv = tuple(str(v) for v in levels) if levels is not None else levels_in_order(frame[condition])
    exclusions: list[Exclusion] = []
    kept: list[str] = []
    for u in levels_in_order(frame[unit]):
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


def require_complete(data: pd.DataFrame, dv: str, within: str, subject: str) -> tuple[pd.DataFrame, tuple[str, ...]]:
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

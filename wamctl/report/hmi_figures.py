"""Bar charts of HMI results per condition, like thesis Figs. 6.28 (means) and 6.29 (medians).

Conventions
-----------
* Input is one units x conditions table per panel (:meth:`wamctl.analysis.hmi_results.HmiResults.wide`), NaN for
  missing cells; each condition's statistic uses the units available for it.
* Error bars: for the mean, the SEM (default) or the SD; for the median, the interquartile range (25th-75th
  percentile), drawn asymmetrically.
* Figures are drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (no pyplot, no display, no global
  state) and saved as PNG to the path given. Nothing else is written.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

logger = logging.getLogger(__name__)

__all__ = ["bar_stats", "save_bar_chart"]

_ERRORS = {"mean": ("sem", "sd", None), "median": ("iqr", None)}


def bar_stats(values: pd.DataFrame, *, statistic: str = "mean", error: str | None = "default") -> pd.DataFrame:
    """Bar heights and error-bar ends per condition.

    Parameters
    ----------
    values : pandas.DataFrame
        Units x conditions (NaN = missing cell).
    statistic : {"mean", "median"}
        Bar height.
    error : {"default", "sem", "sd", "iqr", None}
        Error bar: ``"default"`` is SEM for the mean and IQR for the median; ``None`` draws none.

    Returns
    -------
    pandas.DataFrame
        Index: conditions; columns ``n, value, lower, upper`` (``lower``/``upper`` are the error-bar ends, equal to
        ``value`` when there is no error bar).
    """
    if statistic not in _ERRORS:
        raise ValueError(f"statistic must be 'mean' or 'median', got {statistic!r}")
    if error == "default":
        error = _ERRORS[statistic][0]
    if error not in _ERRORS[statistic]:
        raise ValueError(f"error {error!r} not available for the {statistic}; use one of {_ERRORS[statistic]}")
    n = values.notna().sum().astype(int)
    if statistic == "mean":
        centre = values.mean()
        spread = {"sem": values.std(ddof=1) / np.sqrt(n), "sd": values.std(ddof=1), None: 0.0 * centre}[error]
        lower, upper = centre - spread, centre + spread
    else:
        centre = values.median()
        if error == "iqr":
            lower, upper = values.quantile(0.25), values.quantile(0.75)
        else:
            lower, upper = centre, centre
    out = pd.DataFrame({"n": n, "value": centre, "lower": lower, "upper": upper})
    out.index.name = "condition"
    return out


def save_bar_chart(panels: Mapping[str, pd.DataFrame], path: str | Path, *, statistic: str = "mean",
                   error: str | None = "default", title: str | None = None, dpi: int = 120) -> Path:
    """Draw one bar chart panel per measure, side by side, and save it as PNG.

    Parameters
    ----------
    panels : mapping of str to pandas.DataFrame
        Axis label (e.g. ``"Hits (%)"``, ``"Execution time (s)"``) -> units x conditions table.
    path : str or pathlib.Path
        PNG file to write; the parent directory must exist.
    statistic, error : str
        See :func:`bar_stats`.
    title : str, optional
        Figure title; default ``"Mean (error: SEM)"`` or similar.
    dpi : int, optional
        Resolution.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    if not panels:
        raise ValueError("no panels to draw")
    path = Path(path)
    fig = Figure(figsize=(4.0 * len(panels), 3.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    used_error = None
    for ax, (label, values) in zip(axes, panels.items()):
        st = bar_stats(values, statistic=statistic, error=error)
        used_error = error if error != "default" else _ERRORS[statistic][0]
        x = np.arange(len(st))
        yerr = np.vstack([st["value"] - st["lower"], st["upper"] - st["value"]]).clip(min=0.0)
        ax.bar(x, st["value"], color="0.7", edgecolor="0.2",
               yerr=yerr if used_error else None, capsize=4, error_kw={"elinewidth": 1.0})
        ax.set_xticks(x, [str(c) for c in st.index])
        ax.set_ylabel(label)
        ax.set_xlabel(str(values.columns.name or "condition"))
    fig.suptitle(title or f"{statistic.capitalize()}" + (f" (error bars: {used_error.upper()})" if used_error else ""))
    fig.savefig(path, format="png", dpi=dpi)
    logger.info("wrote %s", path)
    return path

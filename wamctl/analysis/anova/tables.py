"""One line of an ANOVA table, and the JSON-safe and pandas forms shared by every result of the package."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd


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
def quiet_pingouin() -> Iterator[Any]:
    """Import pingouin and silence its pandas-3 deprecation warnings (``inplace=`` in its own code)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*inplace keyword.*")
        warnings.filterwarnings("ignore", category=FutureWarning, module=r"pingouin.*")
        import pingouin

        yield pingouin


def levels_in_order(series: pd.Series) -> tuple[str, ...]:
    """The distinct values of ``series`` as strings, in order of first appearance."""
    return tuple(str(v) for v in pd.unique(series))

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


def rows_to_pandas(rows: Sequence[AnovaRow]) -> pd.DataFrame:
    """ANOVA table lines as a frame: index ``source``, columns ``SS, df, MS, F, p`` (NaN where a line has none)."""
    frame = pd.DataFrame(
        {"SS": [r.ss for r in rows], "df": [r.df for r in rows],
         "MS": [np.nan if r.ms is None else r.ms for r in rows],
         "F": [np.nan if r.f is None else r.f for r in rows],
         "p": [np.nan if r.p is None else r.p for r in rows]},
        index=pd.Index([r.source for r in rows], name="source"),
    )
    return frame


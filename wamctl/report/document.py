"""A small report document: headings, paragraphs, warnings, tables and figures, rendered to Markdown, HTML and
JSON (and, through :mod:`wamctl.commands.common`, to the terminal).

Every report of wamctl is built as a :class:`Document` so that every format carries the same numbers (the JSON
holds every table in full precision). Conventions shared by the formats:

* **Key columns.** A table's key (the joint, the point, the trial, ...) is its index when the index is named or
  is not the default ``0..n-1`` (a ``MultiIndex`` gives several key columns), else ``key=`` names columns, else
  the first column. The key is always shown: first, left-aligned, and in HTML kept in view when a wide table
  scrolls sideways; on the terminal it is repeated in every part of a table split to fit the width.
* **One number format per column** (:func:`format_column`), chosen from the column's values and name: whole
  numbers as integers (and the counts of a row keyed ``n``, :data:`COUNT_ROWS`, under rows of means);
  p-values with three decimals or, when one is below 0.001, in scientific notation;
  otherwise fixed decimals, as many as the column's smallest magnitude needs for ``digits`` significant digits
  (a value typed with fewer decimals, such as a published figure, shows as typed), or scientific notation for
  the whole column when that would take more than 6 decimals or a value reaches 1e6.
* **One file to mail.** ``report.html`` embeds its figures (PNG as ``data:`` URIs, SVG inline); the PNG files
  are written beside it too, for the Markdown.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from wamctl.io import ensure_dir
from wamctl.runs.store import atomic_write_text, json_default

DEFAULT_DIGITS = 4          # significant digits of a column's smallest magnitude
MAX_DECIMALS = 6            # beyond this, a column goes to scientific notation
COUNT_ROWS = frozenset({"n", "N", "count", "n_points", "n_runs"})   # row keys whose cells are counts
_P_COLUMN = re.compile(r"(^|_)(p|p_value|pvalue|p_gg|p_hf|p_holm|p_unc|p_corr|p_adj)(_|$)", re.IGNORECASE)


@dataclass(frozen=True)
class Link:
    """A table cell that links to another file: ``text`` shown, ``href`` relative to the document."""

    text: str
    href: str

    def __str__(self) -> str:
        return self.text


class Table(NamedTuple):
    """A table block: ``name`` (its key in the JSON), the frame as given, caption, significant digits, and the
    key columns (names in :meth:`frame_shown`)."""

    name: str
    df: pd.DataFrame
    caption: str
    digits: int
    key: tuple[str, ...]

    def frame_shown(self) -> pd.DataFrame:
        """The frame as shown: the index as leading key column(s), key columns first."""
        return display_frame(self.df, self.key)[0]

    def cells(self, na: str = "") -> tuple[list[str], list[list[str]], list[bool]]:
        """(column names, rows of formatted cells, per column: is it a key column). A row keyed as a count
        (:data:`COUNT_ROWS`: the ``n`` under Mean, SD, SEM) shows its whole numbers as integers, whatever the
        decimals of their columns."""
        frame, key = display_frame(self.df, self.key)
        cols = [format_column(frame.iloc[:, i], self.digits, str(c), na) for i, c in enumerate(frame.columns)]
        rows = [list(r) for r in zip(*cols)] if cols else []
        is_key = [str(c) in key for c in frame.columns]
        for r, row in enumerate(rows):
            if not any(k and row[c] in COUNT_ROWS for c, k in enumerate(is_key)):
                continue
            for c, k in enumerate(is_key):
                v = frame.iat[r, c]
                if not k and _is_numeric(frame.iloc[:, c]) and not _missing(v) and _whole(v):
                    row[c] = str(int(round(float(v))))
        return [str(c) for c in frame.columns], rows, is_key

    def numeric(self) -> list[bool]:
        """Per shown column: holds numbers (right-aligned, never wrapped)."""
        frame = self.frame_shown()
        return [_is_numeric(frame.iloc[:, i]) for i in range(frame.shape[1])]


def display_frame(df: pd.DataFrame, key: tuple[str, ...] = ()) -> tuple[pd.DataFrame, tuple[str, ...]]:
    """``df`` with its index as leading column(s) when the index carries information, and its key columns
    (moved first)."""
    idx = df.index
    named = any(n is not None for n in idx.names)
    default = isinstance(idx, pd.RangeIndex) and idx.start == 0 and idx.step == 1 and not named
    names = [str(n) if n is not None else ("index" if idx.nlevels == 1 else f"level_{i}")
             for i, n in enumerate(idx.names)]
    if not default and not set(names) & {str(c) for c in df.columns}:
        frame = df.copy()
        frame.index = idx.set_names(names)
        return frame.reset_index(), tuple(names)
    frame = df.reset_index(drop=True)
    cols = [str(c) for c in frame.columns]
    keys = tuple(str(k) for k in key if str(k) in cols) or (tuple(n for n in names if n in cols) if not default
                                                            else ()) or tuple(cols[:1])
    order = [c for c in frame.columns if str(c) in keys] + [c for c in frame.columns if str(c) not in keys]
    return frame[order], keys


# ---------------------------------------------------------------------------------------------- number formats
def _is_numeric(s: pd.Series) -> bool:
    if pd.api.types.is_bool_dtype(s):
        return False
    if pd.api.types.is_numeric_dtype(s):
        return True
    vals = [v for v in s if not _missing(v)]
    return bool(vals) and all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                              for v in vals)


def _whole(v) -> bool:
    """A finite whole number (a count), not a bool."""
    return (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            and math.isfinite(float(v)) and float(v) == round(float(v)) and abs(float(v)) < 1e15)


def _missing(v) -> bool:
    if v is None or v is pd.NA or v is pd.NaT:
        return True
    return isinstance(v, (float, np.floating)) and math.isnan(v)


def _exact_decimals(v: float, limit: int) -> int:
    """Fewest decimals (<= limit) that show ``v`` exactly (to 1e-9 relative), else ``limit``."""
    for d in range(limit + 1):
        if abs(round(v, d) - v) <= 1e-9 * max(1.0, abs(v)):
            return d
    return limit


def column_format(values, digits: int = DEFAULT_DIGITS, name: str = "") -> str:
    """The one format spec of a numeric column (``"d"``, ``".3f"``, ``".3e"``), from its finite values and name.

    Whole numbers below 1e15 -> ``"d"``; p-value columns (``p``, ``p_value``, ``*_p``, ``p_gg``...) -> 3
    decimals, or ``.1e`` when one is below 0.001; otherwise fixed decimals: per value the fewer of (the decimals
    giving ``digits`` significant digits, the decimals showing it exactly), the most over the column; scientific
    (``digits - 1`` decimals) when that is over :data:`MAX_DECIMALS` or a value reaches 1e6.
    """
    v = np.asarray([float(x) for x in values if not _missing(x)], float)
    v = v[np.isfinite(v)]
    if not len(v):
        return "d"
    a = np.abs(v[v != 0])
    if _P_COLUMN.search(name) and (v >= 0).all() and (v <= 1).all():
        return ".1e" if len(a) and a.min() < 1e-3 else ".3f"
    if (np.abs(v) < 1e15).all() and np.all(v == np.round(v)):
        return "d"
    if not len(a):
        return "d"
    if a.max() >= 1e6:
        return f".{digits - 1}e"
    dec = 0
    for x in a:
        exact = _exact_decimals(float(x), MAX_DECIMALS + 1)   # a value typed in (a thesis figure) shows as typed
        dec = max(dec, exact if exact <= MAX_DECIMALS else max(0, digits - 1 - math.floor(math.log10(x))))
    if dec > MAX_DECIMALS:
        return f".{digits - 1}e"
    return f".{dec}f"


def format_value(v, spec: str, na: str = "") -> str:
    if _missing(v):
        return na
    if isinstance(v, Link):
        return v.text
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, float, np.integer, np.floating)):
        x = float(v)
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        if spec == "d":
            return str(int(round(x)))
        return format(x, spec)
    return str(v)


def format_column(s: pd.Series, digits: int = DEFAULT_DIGITS, name: str = "", na: str = "") -> list[str]:
    """The cells of one column as text, in the column's one format (:func:`column_format`)."""
    if _is_numeric(s):
        spec = column_format(s.tolist(), digits, name)
        return [format_value(v, spec, na) for v in s]
    return [format_value(v, "", na) for v in s]


# ---------------------------------------------------------------------------------------------- column labels
# unit suffixes of column names (units in names: velocity_rad_s), longest first, and how a reader writes them
_UNITS: tuple[tuple[tuple[str, ...], str], ...] = (
    (("Nm", "s", "rad"), "N m s/rad"), (("Nm", "s2", "rad"), "N m s\u00b2/rad"), (("Nm", "rad", "s"), "N m/(rad s)"),
    (("kg", "m2"), "kg m\u00b2"), (("Nm", "rad"), "N m/rad"), (("rad", "s2"), "rad/s\u00b2"), (("rad", "s"), "rad/s"),
    (("m", "s"), "m/s"), (("m", "s2"), "m/s\u00b2"), (("Nm",), "N m"), (("N",), "N"), (("rad",), "rad"),
    (("mrad",), "mrad"), (("deg",), "deg"), (("s",), "s"), (("ms",), "ms"), (("us",), "\u00b5s"), (("m",), "m"),
    (("mm",), "mm"), (("kg",), "kg"), (("Hz",), "Hz"), (("pct",), "%"), (("px",), "px"),
)


def split_unit(name: str) -> tuple[str, str]:
    """(what, unit) of a column name whose unit is its suffix: ``speed_peak_rad_s`` -> (``speed peak``,
    ``rad/s``), ``sigma2_pos_Nm_s_rad`` -> (``sigma2 pos``, ``N m s/rad``), ``hit_pct`` -> (``hit``, ``%``);
    (name with spaces for underscores, ``""``) when it has none."""
    parts = str(name).split("_")
    for suffix, unit in _UNITS:
        n = len(suffix)
        if len(parts) > n and tuple(parts[-n:]) == suffix:
            return " ".join(parts[:-n]), unit
    return " ".join(parts), ""


def column_label(name: str) -> str:
    """A column name as a reader writes it: words, then the unit in parentheses with its slash
    (``speed_peak_rad_s`` -> ``speed peak (rad/s)``)."""
    base, dot, tail = str(name).rpartition(".")
    if dot and base and tail.isalnum():                 # a key figure of one joint: rpe_pct.1 -> rpe.1 (%)
        what, unit = split_unit(base)
        return f"{what}.{tail} ({unit})" if unit else f"{what}.{tail}"
    what, unit = split_unit(name)
    if unit and what.endswith(" per"):                  # bytes_per_s -> bytes/s
        return f"{what[:-4]}/{unit}"
    return f"{what} ({unit})" if unit else what


# ---------------------------------------------------------------------------------------------- the document
@dataclass
class Document:
    title: str
    blocks: list[tuple[str, object]] = field(default_factory=list)
    data: dict = field(default_factory=dict)

    def heading(self, text: str) -> Document:
        self.blocks.append(("h2", text))
        return self

    def text(self, text: str) -> Document:
        self.blocks.append(("p", text))
        return self

    def warning(self, text: str) -> Document:
        """Something the reader must act on (shown highlighted, and on the terminal after the tables)."""
        self.blocks.append(("warn", text))
        self.data.setdefault("warnings", []).append(text)
        return self

    def table(self, name: str, df: pd.DataFrame, caption: str = "", digits: int = DEFAULT_DIGITS,
              key: str | list[str] | None = None) -> Document:
        """A table; its key column(s) are its index (when it carries one), else ``key``, else the first column;
        ``digits``: significant digits of each column's smallest magnitude."""
        keys = (key,) if isinstance(key, str) else tuple(key or ())
        self.blocks.append(("table", Table(name, df, caption, int(digits), keys)))
        return self

    def figure(self, path: Path, caption: str = "") -> Document:
        self.blocks.append(("fig", (Path(path), caption)))
        return self

    def tables(self) -> dict[str, pd.DataFrame]:
        return {obj.name: obj.df for kind, obj in self.blocks if kind == "table"}

    # ---------------------------------------------------------------------- renderers
    def to_markdown(self) -> str:
        out = [f"# {self.title}", ""]
        for kind, obj in self.blocks:
            if kind == "h2":
                out += [f"## {obj}", ""]
            elif kind == "p":
                out += [str(obj), ""]
            elif kind == "warn":
                out += [f"> **Warning:** {obj}", ""]
            elif kind == "table":
                out += [markdown_table(obj), ""]
                if obj.caption:
                    out += [f"*{obj.caption}*", ""]
            elif kind == "fig":
                path, caption = obj
                out += [f"![{caption}]({path.name})", ""]
        return "\n".join(out)

    def to_html(self) -> str:
        body = [f"<h1>{html.escape(self.title)}</h1>"]
        for kind, obj in self.blocks:
            if kind == "h2":
                body.append(f"<h2>{html.escape(str(obj))}</h2>")
            elif kind == "p":
                body.append(f"<p>{html.escape(str(obj))}</p>")
            elif kind == "warn":
                body.append(f"<p class='warn'><strong>Warning:</strong> {html.escape(str(obj))}</p>")
            elif kind == "table":
                body.append(html_table(obj))
            elif kind == "fig":
                body.append(html_figure(*obj))
        return (f"<!doctype html><html lang='en'><head><meta charset='utf-8'>"
                f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
                f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>"
                f"<body>{''.join(body)}{_WIDE_TABLES_JS}</body></html>")

    def to_json(self) -> dict:
        tables = {}
        for kind, obj in self.blocks:
            if kind == "table":
                df = obj.df.map(lambda v: v.href if isinstance(v, Link) else v)
                tables[obj.name] = json.loads(df.reset_index().to_json(orient="records", double_precision=15))
        return {"title": self.title, "tables": tables, **self.data}

    def write(self, out_dir: Path, stem: str = "report", formats=("md", "html", "json")) -> list[Path]:
        out_dir = ensure_dir(out_dir, "report directory")
        written = []
        for fmt in formats:
            p = out_dir / f"{stem}.{fmt}"
            if fmt == "md":
                atomic_write_text(p, self.to_markdown())
            elif fmt == "html":
                atomic_write_text(p, self.to_html())
            elif fmt == "json":
                atomic_write_text(p, json.dumps(self.to_json(), indent=2, default=json_default))
            else:
                raise ValueError(f"unknown report format {fmt!r} (md, html, json)")
            written.append(p)
        return written


def key_figures(report_data: dict, limit: int = 32) -> dict[str, float]:
    """The numbers of a report's ``data`` (its JSON beside the tables): scalars, and one level of mappings
    (``rpe_pct.1``, ...), at most ``limit``. Used to compare runs (sweep index, combined report)."""
    out: dict[str, float] = {}
    for k, v in report_data.items():
        if k in ("title", "tables"):
            continue
        if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, (bool, np.bool_)):
            out[k] = float(v)
        elif isinstance(v, dict):
            for kk, vv in v.items():
                if isinstance(vv, (int, float, np.floating, np.integer)) and not isinstance(vv, (bool, np.bool_)):
                    out[f"{k}.{kk}"] = float(vv)
        if len(out) >= limit:
            break
    return dict(list(out.items())[:limit])


# ---------------------------------------------------------------------------------------------- Markdown
def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown_table(table: Table | pd.DataFrame, digits: int = DEFAULT_DIGITS) -> str:
    """A pipe table: key columns left-aligned, numbers right-aligned; links as ``[text](href)``."""
    if isinstance(table, pd.DataFrame):
        table = Table("", table, "", digits, ())
    names, rows, is_key = table.cells()
    frame = table.frame_shown()
    links = [[isinstance(v, Link) for v in frame.iloc[:, i]] for i in range(frame.shape[1])]
    numeric = table.numeric()
    header = "| " + " | ".join(_md_cell(n) for n in names) + " |"
    sep = "|" + "|".join(":---" if k or not num else "---:" for k, num in zip(is_key, numeric)) + "|"
    body = []
    for r, row in enumerate(rows):
        cells = []
        for c, text in enumerate(row):
            v = frame.iat[r, c]
            cells.append(f"[{_md_cell(text)}]({v.href})" if links[c][r] else _md_cell(text))
        body.append("| " + " | ".join(cells) + " |")
    return "\n".join([header, sep, *body])


# ---------------------------------------------------------------------------------------------- HTML
_STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:1180px;margin:1.5em auto;padding:0 1em;color:#222;"
    "line-height:1.4}"
    "h1{font-size:1.6em}h2{font-size:1.25em;margin-top:1.6em}"
    # a table wider than the page scrolls inside its box: a shadow on the side with more columns (CSS only,
    # Lea Verou's scroll shadows), a scrollbar that stays drawn, and a line above it saying so (_WIDE_TABLES_JS)
    ".tw{overflow-x:auto;max-width:100%;margin:0.8em 0;background:"
    "linear-gradient(to right,#fff 30%,rgba(255,255,255,0)) left/2.5em 100% no-repeat local,"
    "linear-gradient(to left,#fff 30%,rgba(255,255,255,0)) right/2.5em 100% no-repeat local,"
    "radial-gradient(farthest-side at 0 50%,rgba(0,0,0,.28),rgba(0,0,0,0)) left/14px 100% no-repeat scroll,"
    "radial-gradient(farthest-side at 100% 50%,rgba(0,0,0,.28),rgba(0,0,0,0)) right/14px 100% no-repeat scroll}"
    ".tw::-webkit-scrollbar{height:10px}.tw::-webkit-scrollbar-thumb{background:#aaa;border-radius:5px}"
    ".tw::-webkit-scrollbar-track{background:#eee}"
    ".wide-note{color:#8a5a00;font-size:0.88em;margin:0.8em 0 -0.5em}"
    "table.t{border-collapse:collapse;font-size:0.92em}"
    "table.t th,table.t td{padding:3px 8px;border-bottom:1px solid #ddd;text-align:right;vertical-align:top}"
    "table.t thead th{vertical-align:bottom;font-weight:600;border-bottom:2px solid #999;max-width:11em;"
    "overflow-wrap:normal;word-break:normal}"
    "table.t td{white-space:nowrap;font-variant-numeric:tabular-nums}"
    "table.t td.txt{white-space:normal;text-align:left;min-width:8em;max-width:32em}table.t th.txt{text-align:left}"
    "table.t .key{position:sticky;left:0;background:#fff;text-align:left;font-weight:600;white-space:nowrap;"
    "border-right:1px solid #ddd}"
    "table.t thead .key{z-index:1}"
    ".cap,figcaption{color:#555;font-size:0.92em}"
    "figure{margin:1em 0}img{max-width:100%;height:auto}"
    ".warn{background:#fff4ce;border-left:4px solid #e0a800;padding:0.5em 0.8em}"
)


# once the page is laid out: above every table wider than its box, how many columns lie beyond the right edge
_WIDE_TABLES_JS = (
    "<script>addEventListener('load',()=>{for(const b of document.querySelectorAll('.tw')){"
    "if(b.scrollWidth<=b.clientWidth+1)continue;const r=b.getBoundingClientRect().right;"
    "const n=[...b.querySelectorAll('thead th')].filter(h=>h.getBoundingClientRect().right>r+1).length;"
    "const p=document.createElement('p');p.className='wide-note';"
    "p.textContent=`\u2192 ${n} more column${n===1?'':'s'} to the right: scroll the table sideways`;"
    "b.before(p);}});</script>")


def _header_html(name: str) -> str:
    """A column name that may wrap after its underscores (never inside a word or number)."""
    return "_<wbr>".join(html.escape(part) for part in name.split("_"))


def html_table(table: Table) -> str:
    names, rows, is_key = table.cells()
    frame = table.frame_shown()
    numeric = table.numeric()
    head = "".join(f"<th scope='col' class='{'key' if k else ('num' if num else 'txt')}'>{_header_html(n)}</th>"
                   for n, k, num in zip(names, is_key, numeric))
    body = []
    for r, row in enumerate(rows):
        cells = []
        for c, text in enumerate(row):
            v = frame.iat[r, c]
            inner = (f"<a href='{html.escape(v.href, quote=True)}'>{html.escape(text)}</a>" if isinstance(v, Link)
                     else html.escape(text))
            if is_key[c]:
                cells.append(f"<th scope='row' class='key'>{inner}</th>")
            else:
                cells.append(f"<td>{inner}</td>" if numeric[c] else f"<td class='txt'>{inner}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    cap = f"<p class='cap'>{html.escape(table.caption)}</p>" if table.caption else ""
    return (f"<div class='tw'><table class='t' data-name='{html.escape(table.name, quote=True)}'>"
            f"<thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table></div>{cap}")


def html_figure(path: Path, caption: str) -> str:
    """A figure embedded in the page: PNG/JPEG as a data URI, SVG inline; a missing file by its name."""
    path = Path(path)
    alt = html.escape(caption or path.stem, quote=True)
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    if path.is_file() and path.suffix.lower() == ".svg":
        svg = path.read_text(errors="replace")
        svg = svg[svg.find("<svg"):] if "<svg" in svg else svg
        return f"<figure role='img' aria-label='{alt}'>{svg}{cap}</figure>"
    if path.is_file():
        mime = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}.get(path.suffix.lower(),
                                                                                      "application/octet-stream")
        src = f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"
    else:
        src = html.escape(path.name, quote=True)
    return f"<figure><img src='{src}' alt='{alt}'>{cap}</figure>"

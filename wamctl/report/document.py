"""A small report document: headings, paragraphs, tables and figures, rendered to Markdown, HTML and JSON.

Every report of wamctl is built as a :class:`Document` so that the three formats always carry the same
numbers (the JSON holds every table in full precision).
"""

from __future__ import annotations

import html
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.runs.store import json_default


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

    def table(self, name: str, df: pd.DataFrame, caption: str = "", digits: int = 4) -> Document:
        self.blocks.append(("table", (name, df, caption, digits)))
        return self

    def figure(self, path: Path, caption: str = "") -> Document:
        self.blocks.append(("fig", (Path(path).name, caption)))
        return self

    # ---------------------------------------------------------------------- renderers
    def to_markdown(self) -> str:
        out = [f"# {self.title}", ""]
        for kind, obj in self.blocks:
            if kind == "h2":
                out += [f"## {obj}", ""]
            elif kind == "p":
                out += [str(obj), ""]
            elif kind == "table":
                name, df, caption, digits = obj
                out += [markdown_table(df, digits), ""]
                if caption:
                    out += [f"*{caption}*", ""]
            elif kind == "fig":
                fname, caption = obj
                out += [f"![{caption}]({fname})", ""]
        return "\n".join(out)

    def to_html(self) -> str:
        body = [f"<h1>{html.escape(self.title)}</h1>"]
        for kind, obj in self.blocks:
            if kind == "h2":
                body.append(f"<h2>{html.escape(str(obj))}</h2>")
            elif kind == "p":
                body.append(f"<p>{html.escape(str(obj))}</p>")
            elif kind == "table":
                name, df, caption, digits = obj
                body.append(_format(df, digits).to_html(border=0, classes="t", na_rep="", escape=True,
                                                         index=not isinstance(df.index, pd.RangeIndex)))
                if caption:
                    body.append(f"<p class='cap'>{html.escape(caption)}</p>")
            elif kind == "fig":
                fname, caption = obj
                body.append(f"<figure><img src='{html.escape(fname)}' alt='{html.escape(caption)}'>"
                            f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
                 "table.t{border-collapse:collapse;margin:1em 0}table.t td,table.t th{padding:3px 10px;"
                 "border-bottom:1px solid #ddd;text-align:right}img{max-width:100%}.cap,figcaption{color:#555}")
        return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{style}</style></head><body>{''.join(body)}</body></html>")

    def to_json(self) -> dict:
        tables = {}
        for kind, obj in self.blocks:
            if kind == "table":
                name, df, _, _ = obj
                tables[name] = json.loads(df.reset_index().to_json(orient="records", double_precision=15))
        return {"title": self.title, "tables": tables, **self.data}

    def write(self, out_dir: Path, stem: str = "report", formats=("md", "html", "json")) -> list[Path]:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        written = []
        for fmt in formats:
            p = out_dir / f"{stem}.{fmt}"
            if fmt == "md":
                p.write_text(self.to_markdown())
            elif fmt == "html":
                p.write_text(self.to_html())
            elif fmt == "json":
                p.write_text(json.dumps(self.to_json(), indent=2, default=json_default))
            else:
                raise ValueError(f"unknown report format {fmt!r} (md, html, json)")
            written.append(p)
        return written


def _format(df: pd.DataFrame, digits: int) -> pd.DataFrame:
    def fmt(v):
        if isinstance(v, (float, np.floating)):
            if math.isnan(v):
                return ""
            if v == round(v) and abs(v) < 1e9:
                return str(int(v))             # counts, degrees of freedom, whole percentages
            if v != 0 and (abs(v) < 10 ** (-digits + 1) or abs(v) >= 1e6):
                return f"{v:.{digits - 1}e}"
            return f"{v:.{digits}f}"
        return str(v)
    return df.map(fmt)


def markdown_table(df: pd.DataFrame, digits: int = 4) -> str:
    f = _format(df.reset_index() if df.index.name or not isinstance(df.index, pd.RangeIndex) else df, digits)
    header = "| " + " | ".join(str(c) for c in f.columns) + " |"
    sep = "|" + "|".join("---:" for _ in f.columns) + "|"
    rows = ["| " + " | ".join(str(v) for v in r) + " |" for r in f.itertuples(index=False)]
    return "\n".join([header, sep, *rows])

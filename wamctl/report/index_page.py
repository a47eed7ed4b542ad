"""``runs/index.html``: every run of a folder in one sortable table (plain HTML and a few lines of JavaScript, no
CDN), each row linked to its report. Rewritten when a run ends and by ``wamctl runs --html``."""

from __future__ import annotations

import html
import os
from pathlib import Path

from wamctl.runs import catalog
from wamctl.runs.store import atomic_write_text

_STYLE = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
.tw{overflow-x:auto;max-width:100%}
table{border-collapse:collapse;width:100%;font-size:14px}
th,td{padding:4px 8px;border-bottom:1px solid #ddd;text-align:left;vertical-align:top}
thead th{cursor:pointer;background:#f3f3f3;position:sticky;top:0;white-space:nowrap}
thead th:after{content:" \\2195";color:#aaa}
.key{position:sticky;left:0;background:#fff;white-space:nowrap;font-weight:600;z-index:1}
thead th.key{background:#f3f3f3;z-index:2}
td.num{text-align:right;white-space:nowrap}
td.nowrap{white-space:nowrap}
.completed{color:#17702a}.failed,.abandoned{color:#b00020;font-weight:bold}.interrupted{color:#a66a00}
"""

_SCRIPT = """
document.querySelectorAll('thead th').forEach(function(th, col){
  th.addEventListener('click', function(){
    var tb = th.closest('table').tBodies[0], rows = Array.from(tb.rows);
    var dir = th.dataset.dir === 'asc' ? -1 : 1; th.dataset.dir = dir === 1 ? 'asc' : 'desc';
    rows.sort(function(a, b){
      var key = function(r){ return r.cells[col].dataset.key || r.cells[col].textContent; };
      var x = key(a), y = key(b);
      var nx = parseFloat(x), ny = parseFloat(y);
      if (!isNaN(nx) && !isNaN(ny)) return dir * (nx - ny);
      return dir * x.localeCompare(y);
    });
    rows.forEach(function(r){ tb.appendChild(r); });
  });
});
"""


def index_html(folder: Path, entries: list[catalog.RunEntry]) -> str:
    """The page for ``entries`` (links relative to ``folder``)."""
    e_ = html.escape
    rows = []
    for e in entries:
        rel = os.path.relpath(e.path, folder)
        if e.report is None and e.manifest_status == "completed":   # its report is written right after the run
            e.report = str(Path(e.path) / "report.html")
        report = os.path.relpath(e.report, folder) if e.report else None
        name = f'<a href="{e_(report)}">{e_(e.name)}</a>' if report else e_(e.name)
        dur = "" if e.duration_s is None else f"{e.duration_s:.3f}"
        # the run (its name, linked to its report) is the key column: first, kept in view when the table scrolls
        rows.append(
            "<tr>"
            f"<th scope='row' class='key'>{name}</th>"
            f'<td class="nowrap">{e_(catalog.format_start(e.start_utc))}</td>'
            f'<td class="txt">{e_(e.kind)}</td>'
            f'<td class="{e_(e.status.split()[0].rstrip("?"))} txt" title="{e_(e.reason or "")}">{e_(e.status)}</td>'
            f'<td class="num" data-key="{dur}">{e_(catalog.format_duration(e.duration_s))}</td>'
            f'<td class="txt">{e_(e.backend)}</td><td class="txt">{e_(e.headline or "-")}</td>'
            f'<td class="txt"><a href="{e_(rel)}/">{e_(Path(e.path).name)}</a></td>'
            "</tr>")
    heads = "<th scope='col' class='key'>run</th>" + "".join(
        f"<th scope='col'>{h}</th>" for h in ("start (UTC)", "kind", "status", "duration", "backend", "figure",
                                              "run directory"))
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>wamctl runs</title>"
            f"<style>{_STYLE}</style></head><body>\n<h1>Runs in {e_(str(folder))}</h1>\n"
            f"<p>{len(entries)} runs, newest first; click a column's title to sort by it.</p>\n"
            f"<div class='tw'><table data-name='runs'><thead><tr>{heads}</tr></thead><tbody>\n" + "\n".join(rows) +
            f"\n</tbody></table></div>\n<script>{_SCRIPT}</script>\n</body></html>\n")


def write_index(folder: Path) -> Path:
    """Rewrite ``folder/index.html`` from the run directories under ``folder``."""
    folder = Path(folder)
    path = folder / "index.html"
    atomic_write_text(path, index_html(folder, catalog.list_runs([folder])))
    return path

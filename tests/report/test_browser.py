"""The reports as a browser shows them: every kind of report.html rendered by headless Chromium at 1280 px and
checked from the rendered page (not from the HTML text): every table shows its key column, numbers sit on one
line, nothing is wider than the viewport (a table wider than its column scrolls inside its box, with the key
column kept in view), and every image loads from the file itself (one file to mail).

Screenshots of every report go to the test's tmp dir (``<tmp>/screenshots/<kind>.png``) for a person to look
at. Chromium is Debian's ``chromium`` package; ``make test`` installs it when it is missing (Makefile target
``browser``). The runs come from tests/cli_runs.py (one small run of every kind per session)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from once import make_once

VIEWPORT_PX = 1280
SHOT_HEIGHT_PX = 9000      # a window this tall holds every report; the screenshot is cut to the page's height

# what the page reports about itself once loaded (written into a <pre> that --dump-dom then prints)
CHECK_JS = r"""
<script>
window.addEventListener('load', () => {
  const vw = window.innerWidth, bottom = document.body.getBoundingClientRect().bottom;
  const out = {viewport: vw, height: Math.ceil(bottom) + 24,
    page_width: document.documentElement.scrollWidth, tables: [], images: [], too_wide: [], split_numbers: [],
    wide_notes: [...document.querySelectorAll('.wide-note')].map(p => p.textContent), hidden_columns: {}};
  const inScroll = el => el.closest('.tw') !== null && !el.classList.contains('tw');
  for (const el of document.body.querySelectorAll('*')) {
    const r = el.getBoundingClientRect();
    if (r.width > 0 && r.right > vw + 0.5 && !inScroll(el)) out.too_wide.push(el.tagName + ' ' + Math.round(r.right));
  }
  for (const t of document.querySelectorAll('table')) {
    const box = t.closest('.tw');
    const head = t.querySelector('thead th');
    const rows = [...t.querySelectorAll('tbody tr')];
    const keys = rows.map(tr => tr.firstElementChild);
    if (box) { const right = box.getBoundingClientRect().right;
      out.hidden_columns[t.dataset.name || '?'] =
        [...t.querySelectorAll('thead th')].filter(h => h.getBoundingClientRect().right > right + 1).length; }
    out.tables.push({name: t.dataset.name || '?', key: head ? head.innerText.replace(/\s+/g, '') : '',
      key_marked: !!head && head.classList.contains('key') && keys.every(c => c.classList.contains('key')),
      key_values: keys.map(c => c.innerText.trim()),
      scrolls: box ? box.scrollWidth > box.clientWidth + 1 : false,
      key_sticky: !!head && getComputedStyle(head).position === 'sticky',
      box_right: box ? box.getBoundingClientRect().right : t.getBoundingClientRect().right});
    for (const c of t.querySelectorAll('tbody td:not(.txt), tbody th')) {
      const range = document.createRange();
      range.selectNodeContents(c);
      const lines = new Set([...range.getClientRects()].map(q => Math.round(q.top)));
      if (lines.size > 1) out.split_numbers.push((t.dataset.name || '?') + ': ' + c.innerText);
    }
  }
  for (const img of document.images)
    out.images.push({embedded: img.src.startsWith('data:'), loaded: img.complete && img.naturalWidth > 0,
                     width: img.getBoundingClientRect().width});
  const pre = document.createElement('pre');
  pre.id = 'wamctl-check';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>
"""

# key columns the issue found missing in the HTML: (report, table) -> key
EXPECTED_KEYS = {("rotation", "rotation"): "joint", ("diagnosis", "summary"): "joint",
                 ("friction_sweep", "friction_parameters"): "joint", ("ift", "thesis_table_5_1"): "joint",
                 ("ift", "ift_gains"): "joint", ("hmi_block", "trials"): "trial", ("combined", "runs"): "run",
                 ("sweep", "points"): "point", ("runs_index", "runs"): "run"}


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def render(browser: str, html: Path, work: Path, name: str) -> dict:
    """Load ``html`` (a copy with the check script) at 1280 px; the page's own findings, and its screenshot
    written to ``work/screenshots/<name>.png``."""
    page = work / "pages" / f"{name}.html"
    page.parent.mkdir(exist_ok=True)
    text = html.read_text()
    page.write_text(text.replace("</body>", CHECK_JS + "</body>"))
    shot = work / "screenshots" / f"{name}.png"
    shot.parent.mkdir(exist_ok=True)
    r = subprocess.run([browser, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                        "--no-first-run", "--disable-extensions", f"--user-data-dir={work / 'profiles' / name}",
                        f"--window-size={VIEWPORT_PX},{SHOT_HEIGHT_PX}", "--virtual-time-budget=10000",
                        f"--screenshot={shot}", "--dump-dom", page.as_uri()],
                       capture_output=True, text=True, timeout=180)
    m = re.search(r'<pre id="wamctl-check">(.*?)</pre>', r.stdout, re.S)
    assert m, f"{name}: the page did not report (chromium exit {r.returncode}): {r.stderr[-1500:]}"
    found = json.loads(m.group(1).replace("&lt;", "<").replace("&gt;", ">").replace("&amp;", "&"))
    _crop(shot, found["height"])
    return found


def _crop(png: Path, height: int) -> None:
    from PIL import Image
    if png.is_file():
        with Image.open(png) as im:
            cut = im.crop((0, 0, im.width, min(im.height, max(1, height))))
        cut.save(png)


@pytest.fixture(scope="module")
def rendered(small_runs, tmp_path_factory):
    browser = chromium()
    if browser is None:
        pytest.skip("Debian's chromium is not installed and could not be (`make test` runs `apt-get install -y "
                    "chromium` when it is missing; this machine refused it)")

    def make(work: Path):            # once for the session's xdist workers (tests/once.py): Chromium is slow
        with ThreadPoolExecutor(max_workers=4) as pool:
            jobs = {name: pool.submit(render, browser, html, work, name) for name, html in small_runs.reports.items()}
            return {name: job.result() for name, job in jobs.items()}, work

    found, work = make_once(tmp_path_factory, "browser_rendered", make)
    print(f"screenshots: {work / 'screenshots'}")
    return found, work


def test_every_kind_of_report_is_rendered(rendered, small_runs):
    found, work = rendered
    assert set(found) == {"rotation", "friction_sweep", "ift", "hmi_block", "measured", "diagnosis", "combined",
                          "sweep", "hmi_results", "runs_index", "compare"}
    for name in found:
        assert (work / "screenshots" / f"{name}.png").stat().st_size > 20_000, name


def test_every_table_shows_its_key_column(rendered):
    found, _ = rendered
    for name, page in found.items():
        assert page["tables"], f"{name}: no table"
        for t in page["tables"]:
            assert t["key_marked"] and t["key"], f"{name} {t['name']}: no key column"
            assert all(t["key_values"]), f"{name} {t['name']}: a row without its key: {t['key_values']}"
        keys = {t["name"]: t["key"] for t in page["tables"]}
        for (report, table), key in EXPECTED_KEYS.items():
            if report == name:
                assert keys.get(table) == key, f"{name} {table}: key {keys.get(table)!r}, expected {key!r}"


def test_nothing_is_wider_than_the_viewport(rendered):
    found, _ = rendered
    for name, page in found.items():
        assert page["viewport"] == VIEWPORT_PX
        assert page["page_width"] <= VIEWPORT_PX, f"{name}: the page scrolls sideways ({page['page_width']} px)"
        assert not page["too_wide"], f"{name}: wider than the viewport: {page['too_wide'][:5]}"
        for t in page["tables"]:
            assert t["box_right"] <= VIEWPORT_PX + 0.5, f"{name} {t['name']}"
            if t["scrolls"]:       # allowed, inside its box, as long as the key column stays in view
                assert t["key_sticky"], f"{name} {t['name']}: scrolls sideways without keeping its key column"


def test_numbers_are_never_wrapped(rendered):
    found, _ = rendered
    for name, page in found.items():
        assert not page["split_numbers"], f"{name}: cells on two lines: {page['split_numbers'][:5]}"


def test_every_image_loads_from_the_file_itself(rendered):
    found, _ = rendered
    n = 0
    for name, page in found.items():
        for img in page["images"]:
            assert img["embedded"], f"{name}: an image is not embedded in report.html"
            assert img["loaded"] and 0 < img["width"] <= VIEWPORT_PX, f"{name}: {img}"
            n += 1
    assert n >= 12       # rotation 2, friction 2, IFT 4, HMI 1, measured 1, diagnosis 4, HMI results 2 ...

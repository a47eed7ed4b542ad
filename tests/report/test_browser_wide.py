"""A table wider than the page at 1280 px (issue 32: the IFT tables of the README's example, seven joints over
twenty-odd iterations, were cut off on the right with nothing saying there was more): it scrolls inside its
box with the key column kept in view, and a line above it says how many columns lie to the right.

Rendered by headless Chromium as in tests/report/test_browser.py (Debian's ``chromium``); the screenshot is
written to ``<tmp>/screenshots/wide.png``."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_browser import VIEWPORT_PX, chromium, render

from wamctl.report.document import Document

ITERATIONS = 24


def _wide_document() -> Document:
    rng = np.random.default_rng(32)
    j = pd.DataFrame(rng.uniform(1e-6, 2e-4, (7, ITERATIONS + 1)), columns=["initial", *map(str, range(1,
                                                                                           ITERATIONS + 1))])
    j.index = pd.Index(range(1, 8), name="joint")
    doc = Document("Iterative feedback tuning: a long run")
    doc.table("ift_J", j, "J per joint and iteration")
    doc.table("narrow", j.iloc[:, :3], "three columns: fits")
    return doc


@pytest.fixture(scope="module")
def wide_page(tmp_path_factory):
    browser = chromium()
    if browser is None:
        pytest.skip("Debian's chromium is not installed (`apt-get install -y chromium`)")
    work = tmp_path_factory.mktemp("wide")
    html = work / "report.html"
    html.write_text(_wide_document().to_html())
    found = render(browser, html, work, "wide")
    print(f"screenshot: {work / 'screenshots' / 'wide.png'}")
    return found, html


def test_a_wide_table_scrolls_in_its_box_and_says_how_many_columns_are_hidden(wide_page):
    found, _ = wide_page
    assert found["page_width"] <= VIEWPORT_PX and not found["too_wide"]
    tables = {t["name"]: t for t in found["tables"]}
    wide, narrow = tables["ift_J"], tables["narrow"]
    assert wide["scrolls"] and wide["key_sticky"] and wide["box_right"] <= VIEWPORT_PX
    assert not narrow["scrolls"]
    notes = found["wide_notes"]
    assert len(notes) == 1, notes                       # above the wide table only
    hidden = int(notes[0].split()[1])
    assert notes[0] == f"\u2192 {hidden} more columns to the right: scroll the table sideways"
    assert 1 <= hidden <= ITERATIONS - 5                # most columns are in view at 1280 px
    assert hidden == found["hidden_columns"]["ift_J"]

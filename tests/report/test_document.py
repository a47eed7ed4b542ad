"""The report document: key columns in every format, one number format per column, figures embedded in
report.html, links and warnings."""

from __future__ import annotations

import base64
import re

import numpy as np
import pandas as pd
import pytest

from wamctl.report.document import Document, Link, column_format, format_column, key_figures, markdown_table


def joint_table(joints) -> pd.DataFrame:
    df = pd.DataFrame({"rpe_pct": np.linspace(0.2, 1.9, len(joints)), "final_error_rad": 0.001 * np.arange(
        1, len(joints) + 1)}, index=pd.Index(joints, name="joint"))
    return df


@pytest.mark.parametrize("index", [pd.RangeIndex(1, 8, name="joint"), pd.RangeIndex(1, 8, 3, name="joint"),
                                  pd.Index([2, 6], name="joint"), pd.RangeIndex(1, 8)],
                         ids=["1..7", "1,4,7", "2,6", "unnamed 1..7"])
def test_the_key_column_is_in_every_format(index):
    """The issue's bug: an index of joints 1..7 or 1, 4, 7 is a RangeIndex, which the HTML left out."""
    df = pd.DataFrame({"rpe_pct": np.linspace(0.2, 1.9, len(index))}, index=index)
    doc = Document("t").table("rotation", df)
    key = index.name or "index"
    md = doc.to_markdown().splitlines()
    assert md[2].startswith(f"| {key} | rpe_pct |") and md[3].startswith("|:---|---:|")
    assert [ln.split("|")[1].strip() for ln in md[4:4 + len(index)]] == [str(j) for j in index]
    html = doc.to_html()
    assert f"<th scope='col' class='key'>{key}</th>" in html
    assert re.findall(r"<th scope='row' class='key'>(\d+)</th>", html) == [str(j) for j in index]
    names, rows, is_key = doc.blocks[0][1].cells()
    assert names[0] == key and is_key[0] and [r[0] for r in rows] == [str(j) for j in index]


def test_a_plain_table_keys_on_its_first_column_or_the_one_named():
    df = pd.DataFrame({"value": [1.5, 2.5], "trial": [3, 4]})
    names, _, is_key = Document("t").table("a", df).blocks[0][1].cells()
    assert names == ["value", "trial"] and is_key == [True, False]
    names, rows, is_key = Document("t").table("a", df, key="trial").blocks[0][1].cells()
    assert names == ["trial", "value"] and is_key == [True, False] and rows[0] == ["3", "1.5"]


def test_one_number_format_per_column():
    # the examples: 9.811e-04 beside 0.0049, and 1.200 beside 2
    assert format_column(pd.Series([9.811e-04, 0.0049, 0.0123])) == ["9.811e-04", "4.900e-03", "1.230e-02"]
    assert format_column(pd.Series([0.00098, 0.0049])) == ["0.00098", "0.00490"]
    assert format_column(pd.Series([1.2, 2.0])) == ["1.2", "2.0"]
    # tiny values: scientific for the whole column (IFT J showed 0.0000 in every cell)
    assert format_column(pd.Series([1.197e-05, 5.4e-07, 1.1e-06])) == ["1.197e-05", "5.400e-07", "1.100e-06"]
    # counts stay integers, published figures show as printed, NaN is empty (or "-" on the terminal)
    assert format_column(pd.Series([4.0, 16.0, 8.0])) == ["4", "16", "8"]
    assert format_column(pd.Series([1.0876, 0.2342, 5.4132])) == ["1.0876", "0.2342", "5.4132"]
    assert format_column(pd.Series([0.5, np.nan]), na="-") == ["0.5", "-"]
    # p-values: three decimals, or scientific once one is below 0.001
    assert column_format([0.03, 0.54], name="p") == ".3f"
    assert column_format([0.03, 1e-12], name="whiteness_p_after") == ".1e"
    assert column_format([2.5e7, 3.5]) == ".3e"
    assert format_column(pd.Series([True, False])) == ["yes", "no"]


def test_every_cell_of_a_column_has_the_same_decimals():
    rng = np.random.default_rng(3)
    for scale in (1e-7, 1e-3, 1.0, 1e3, 1e5):
        cells = format_column(pd.Series(rng.normal(0, scale, 40)))
        decimals = {len(c.split(".")[1].split("e")[0]) if "." in c else 0 for c in cells}
        assert len(decimals) == 1, (scale, cells[:5])
        assert len({("e" in c) for c in cells}) == 1


def test_figures_are_embedded_so_the_report_is_one_file(tmp_path):
    png = tmp_path / "fig.png"
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(2, 1))
    ax.plot([0, 1], [0, 1])
    fig.savefig(png)
    plt.close(fig)
    doc = Document("t").figure(png, "a line")
    html = doc.to_html()
    m = re.search(r"<img src='data:image/png;base64,([^']+)' alt='a line'>", html)
    assert m and base64.b64decode(m.group(1)) == png.read_bytes()
    assert "![a line](fig.png)" in doc.to_markdown()        # the Markdown keeps the file beside it


def test_links_warnings_and_json(tmp_path):
    df = pd.DataFrame({"run": ["r1"], "report": [Link("report", "a b/report.html")]}).set_index("run")
    doc = Document("t").table("runs", df).warning("gains at their bounds")
    assert "<a href='a b/report.html'>report</a>" in doc.to_html()
    assert "| r1 | [report](a b/report.html) |" in doc.to_markdown()
    assert "> **Warning:** gains at their bounds" in doc.to_markdown()
    j = doc.to_json()
    assert j["tables"]["runs"] == [{"run": "r1", "report": "a b/report.html"}] and j["warnings"]
    written = doc.write(tmp_path / "out")
    assert [p.name for p in written] == ["report.md", "report.html", "report.json"]
    assert not list((tmp_path / "out").glob(".*.tmp"))


def test_markdown_escapes_bars_and_keeps_legacy_callers():
    df = pd.DataFrame({"a": ["x|y"], "b": [0.25]})
    assert "x\\|y" in markdown_table(df, 3)


def test_key_figures_flatten_one_level():
    assert key_figures({"title": "x", "rpe_pct": {"1": 0.5, "7": 1.5}, "n": 3, "ok": True, "name": "a"}) == \
        {"rpe_pct.1": 0.5, "rpe_pct.7": 1.5, "n": 3.0}


def test_effect_params_leave_what_is_not_identified_to_its_column():
    """A payload from a sweep of one joint (nothing identified) showed ``mass_kg=not identified, com_m=[not
    identified, ...], com_x_m=not identified, ...`` in its params cell, ten lines at 80 columns, beside the column
    that names them already."""
    from wamctl.report.diagnosis import effects_table

    params = {"mass_kg": None, "com_m": [None, None, None], "joints_fitted": [4], "com_x_m": None,
              "width_rad": 0.0123456, "com_partly_m": [0.01, None, 0.02]}
    result = {"joints": {"4": {"effects": [{"name": "payload", "params": params, "not_identified": ["mass_kg"],
                                            "evidence": {"p_value": 1e-9, "delta_bic": -40.0, "test": "nested"}}]}}}
    row = effects_table(result).iloc[0]
    assert row["params"] == "joints_fitted=[4], width_rad=0.01235, com_partly_m=[0.01, not identified, 0.02]"
    assert row["not identified"] == "mass_kg"
    result["joints"]["4"]["effects"][0]["params"] = {"mass_kg": None}
    assert effects_table(result).iloc[0]["params"] == "-"

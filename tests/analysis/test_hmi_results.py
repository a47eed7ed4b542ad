"""Tests of wamctl.analysis.hmi_results (import, tables, analysis) and wamctl.report.hmi_figures.

The thesis fixtures (tests/fixtures/hmi/thesis_*.csv) are the per-location and per-subject values printed in thesis
Tables 6.2-6.4, 6.8 and 6.10, in the summary import format; thesis_printed.yaml holds the printed summary rows and
ANOVA tables 6.5, 6.6, 6.9, 6.11. Nothing is read from ../shared.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import yaml

from wamctl.analysis.hmi_csv import read_hmi_csv, read_summary_csv, read_trials_csv
from wamctl.analysis.hmi_results import HmiResults, summarise_trials
from wamctl.errors import DataFormatError
from wamctl.report.hmi_figures import bar_stats, save_bar_chart

FIXTURES = Path(__file__).parents[1] / "fixtures" / "hmi"
PRINTED = yaml.safe_load((FIXTURES / "thesis_printed.yaml").read_text())
ANOVA_TABLES = ("table_6_5", "table_6_6", "table_6_9", "table_6_11")


def assert_printed(value: float, printed: str, what: str = "") -> None:
    """``value`` rounds to ``printed`` at its printed precision (half a unit of the last printed digit)."""
    decimals = len(printed.split(".")[1]) if "." in printed else 0
    assert abs(value - float(printed)) <= 0.5 * 10.0 ** -decimals + 1e-12, f"{what}: {value!r} vs printed {printed}"


def last_digit(printed: str) -> float:
    return 10.0 ** -(len(printed.split(".")[1]) if "." in printed else 0)


def load(name: str) -> HmiResults:
    return read_hmi_csv(FIXTURES / name)


# ------------------------------------------------------------------------------------------- thesis fixtures


def test_thesis_fixtures_import() -> None:
    filters = load("thesis_t6_2_t6_3_filters.csv")
    assert filters.unit_kind == "location"
    assert filters.conditions == ("none", "MA150", "MA300", "MA500", "WMA150", "WMA300")
    assert filters.units == tuple(f"P{i}" for i in range(1, 9))
    assert filters.measures == ("hit_rate", "hit_pct", "mean_time_s")
    assert filters.wide("hit_pct").loc["P2", "none"] == 70.0
    assert filters.wide("hit_rate").loc["P2", "none"] == pytest.approx(0.70)
    assert filters.wide("mean_time_s").loc["P7", "WMA300"] == 28.0
    subjects = load("thesis_t6_10_subjects.csv")
    assert subjects.unit_kind == "subject"
    assert subjects.units == tuple(str(i) for i in range(1, 10))
    wide = subjects.wide("hit_pct")
    assert wide.shape == (9, 6)
    assert wide.loc["9"].isna().tolist() == [False, True, True, False, True, True]
    assert wide.loc["2", "E1"] == 32.0


@pytest.mark.parametrize("table", ANOVA_TABLES)
def test_analyse_reproduces_printed_anova(table: str) -> None:
    printed = PRINTED["anova"][table]
    analysis = load(printed["fixture"]).analyse()
    assert analysis.measures == ("hit_rate", "mean_time_s")
    for measure in analysis.measures:
        res = analysis.one_way[measure]
        exp = printed[measure]
        for line, row in (("between", res.between), ("within", res.within), ("total", res.total)):
            assert row.df == exp[line]["df"]
            assert_printed(row.ss, exp[line]["ss"], f"{table} {measure} {line} SS")
            if "ms" in exp[line]:
                assert_printed(row.ms, exp[line]["ms"], f"{table} {measure} {line} MS")
        assert_printed(res.f, exp["between"]["f"], f"{table} {measure} F")
        assert_printed(res.p, exp["between"]["p"], f"{table} {measure} p")


def test_table_6_11_analysis_reports_exclusion_and_rm_anova() -> None:
    analysis = load("thesis_t6_10_subjects.csv").analyse()
    assert [tuple(e) for e in analysis.exclusions] == [
        ("9", "missing E2: no data; E3: no data; E5: no data; E6: no data")]
    assert analysis.complete.units == tuple(str(i) for i in range(1, 9))
    assert analysis.one_way["hit_rate"].apa() == "F(5, 42) = 2.86, p = 0.0262"
    rm = analysis.rm["hit_rate"]
    assert rm.df == (5, 35)
    assert round(rm.f, 2) == 3.04 and round(rm.p, 3) == 0.022  # issue 8
    assert round(rm.sphericity.eps_gg, 3) == 0.643 and round(rm.sphericity.p_gg, 3) == 0.047
    assert rm.sphericity.assumed()
    assert not analysis.rm["mean_time_s"].sphericity.assumed()
    assert len(analysis.pairwise["hit_rate"].comparisons) == 15
    frames = analysis.to_pandas()
    assert {"table_hit_pct", "table_mean_time_s", "anova_hit_rate", "rm_anova_hit_rate", "pairwise_hit_rate",
            "exclusions"} <= set(frames)
    assert frames["exclusions"]["unit"].tolist() == ["9"]


def test_analysis_json_carries_every_number() -> None:
    analysis = load("thesis_t6_10_subjects.csv").analyse()
    d = json.loads(json.dumps(analysis.to_dict(), allow_nan=False))
    assert d["complete_cases"]["exclusions"] == [
        {"unit": "9", "reason": "missing E2: no data; E3: no data; E5: no data; E6: no data"}]
    between = d["one_way_anova"]["hit_rate"]["table"][0]
    assert_printed(between["ss"], "0.37364")
    assert_printed(between["F"], "2.86")
    within = d["one_way_anova"]["mean_time_s"]["table"][1]
    assert_printed(within["ss"], "3277.04")
    assert within["df"] == 42
    assert d["rm_anova"]["hit_rate"]["df_error"] == 35
    assert "p_gg" in d["rm_anova"]["hit_rate"]["sphericity"]
    table = d["tables"]["hit_pct"]
    assert table["columns"] == ["E1", "E2", "E3", "E4", "E5", "E6"]
    assert table["index"][-4:] == ["Mean", "SD", "SEM", "n"]
    assert table["data"][8][1] is None  # subject 9, E2: missing cell as null
    assert table["data"][1][0] == 32.0  # subject 2, E1 as printed
    assert table["data"][-1] == [9, 8, 8, 9, 8, 8]


def test_location_results_skip_repeated_measures_by_default() -> None:
    analysis = load("thesis_t6_4_four_dir_profiles.csv").analyse()
    assert analysis.rm == {} and analysis.pairwise == {} and analysis.exclusions == ()
    forced = load("thesis_t6_4_four_dir_profiles.csv").analyse(["hit_rate"], repeated=True)
    assert forced.rm["hit_rate"].df == (2, 14)


@pytest.mark.parametrize("key", list(PRINTED["summary_rows"]))
def test_tables_match_printed_summary_rows(key: str) -> None:
    """Average and 'SEM' rows of Tables 6.2-6.4, 6.8, 6.10 within one unit of the last printed digit (they are
    rounded or truncated), except the listed printed slips. The thesis' 'SEM' row is the sample SD."""
    spec = PRINTED["summary_rows"][key]
    table = load(spec["fixture"]).table(spec["measure"])
    slips = {(row, cond): computed for t, row, cond, computed in PRINTED["inconsistent_summary_values"] if t == key}
    for row_name, table_row in (("average", "Mean"), ("sem_row", "SD")):
        for cond, printed in zip(spec["conditions"], spec[row_name]):
            value = table.loc[table_row, cond]
            close = abs(value - float(printed)) <= last_digit(printed) + 1e-9
            if (row_name, cond) in slips:
                assert not close, f"{key} {row_name} {cond}: listed as a slip but matches"
                assert_printed(value, slips[(row_name, cond)])
            else:
                assert close, f"{key} {row_name} {cond}: {value} vs printed {printed}"
    n = table.loc["n"]
    assert np.allclose(table.loc["SEM"], table.loc["SD"] / np.sqrt(n))


def test_table_layout_and_available_cases() -> None:
    table = load("thesis_t6_10_subjects.csv").table("hit_pct")
    assert list(table.index) == [str(i) for i in range(1, 10)] + ["Mean", "SD", "SEM", "n"]
    assert table.loc["n"].tolist() == [9, 8, 8, 9, 8, 8]  # printed Average row includes subject 9 in E1, E4
    assert table.loc["Mean", "E1"] == pytest.approx(442 / 9)
    stats = load("thesis_t6_10_subjects.csv").condition_stats("hit_pct", complete=True)
    assert stats["n"].tolist() == [8] * 6
    assert stats.loc["E1", "mean"] == pytest.approx(405 / 8)
    assert stats.loc["E2", "median"] == 75.0


# ---------------------------------------------------------------------------------------------- raw trials


def test_trials_summarised_per_subject_and_location() -> None:
    trials = read_trials_csv(FIXTURES / "trials_small.csv")
    assert len(trials) == 16 and trials["time_s"].isna().sum() == 1
    per_subject = read_hmi_csv(FIXTURES / "trials_small.csv")  # two subjects -> per subject
    assert per_subject.unit_kind == "subject"
    got = per_subject.data.set_index(["subject", "condition"])
    assert got["hits"].to_dict() == {("S1", "A"): 3, ("S1", "B"): 1, ("S2", "A"): 4, ("S2", "B"): 2}
    assert got["attempts"].tolist() == [4, 4, 4, 4]
    assert got["hit_rate"].tolist() == [0.75, 0.25, 1.0, 0.5]
    assert got["mean_time_s"].tolist() == pytest.approx([12.0, 20.0, 11.0, 20.0])
    per_location = summarise_trials(trials, unit="location")
    got = per_location.data.set_index(["location", "condition"])
    assert got.loc[("P1", "A"), "hit_rate"] == 0.75 and got.loc[("P2", "A"), "hit_rate"] == 1.0
    assert got.loc[("P1", "B"), "hit_rate"] == 0.25 and got.loc[("P2", "B"), "hit_rate"] == 0.5
    assert got["mean_time_s"].to_dict() == pytest.approx(
        {("P1", "A"): 12.0, ("P2", "A"): 32 / 3, ("P1", "B"): 19.0, ("P2", "B"): 21.0})


def test_trials_expanded_from_tables_6_2_6_3_reproduce_table_6_5(tmp_path: Path) -> None:
    """Synthetic raw trials: each location of Tables 6.2/6.3 as 10 attempts with the printed hit count and times
    alternating +-0.5 s around the printed mean; summarised per location they give Table 6.5 again."""
    summary = load("thesis_t6_2_t6_3_filters.csv").data
    lines = ["subject,condition,location,attempt,hit,time_s"]
    for row in summary.itertuples(index=False):
        n_hits = round(row.hit_pct / 10)
        for attempt in range(1, 11):
            time_s = row.mean_time_s + (0.5 if attempt % 2 else -0.5)
            lines.append(f"S1,{row.condition},{row.location},{attempt},{int(attempt <= n_hits)},{time_s:.2f}")
    path = tmp_path / "trials.csv"
    path.write_text("\n".join(lines) + "\n")
    results = read_hmi_csv(path)
    assert results.unit_kind == "location"  # one subject
    assert results.data["attempts"].eq(10).all()
    analysis = results.analyse()
    exp = PRINTED["anova"]["table_6_5"]
    for measure in ("hit_rate", "mean_time_s"):
        assert_printed(analysis.one_way[measure].between.ss, exp[measure]["between"]["ss"])
        assert_printed(analysis.one_way[measure].within.ss, exp[measure]["within"]["ss"])
        assert_printed(analysis.one_way[measure].f, exp[measure]["between"]["f"])
        assert_printed(analysis.one_way[measure].p, exp[measure]["between"]["p"])


def test_summary_with_counts(tmp_path: Path) -> None:
    path = tmp_path / "s.csv"
    path.write_text("location,condition,hits,attempts,mean_time_s,note\n"
                    "P1,a,9,10,12.5,\nP1,b,7,10,NA,slow\nP2,a,10,10,11.0,\nP2,b,8,10,13.0,\n")
    res = read_summary_csv(path)
    assert res.data["hit_rate"].tolist() == [0.9, 0.7, 1.0, 0.8]
    assert res.data["hit_pct"].tolist() == pytest.approx([90.0, 70.0, 100.0, 80.0])
    cc = res.complete_cases()
    assert list(cc.exclusions) == [("P1", "missing b: no mean_time_s")]
    assert res.complete_cases(["hit_rate"]).units == ("P1", "P2")


def test_summary_without_time_analyses_hits_only(tmp_path: Path) -> None:
    path = tmp_path / "s.csv"
    path.write_text("subject,condition,hit_pct\n" + "".join(
        f"{s},{c},{v}\n" for s, row in zip("ABC", [[50, 70], [60, 90], [40, 60]]) for c, v in zip("xy", row)))
    res = read_hmi_csv(path)
    assert res.measures == ("hit_rate", "hit_pct")
    analysis = res.analyse()
    assert analysis.measures == ("hit_rate",)
    assert analysis.rm["hit_rate"].df == (1, 2)
    (only_pair,) = analysis.pairwise["hit_rate"].comparisons
    assert only_pair.p_holm == only_pair.p_unc  # one comparison: Holm changes nothing
    assert only_pair.t == pytest.approx(-7.0)  # x - y = -0.2, -0.3, -0.2: mean -0.2333, SEM 0.0333
    with pytest.raises(DataFormatError, match="'mean_time_s' not available"):
        res.wide("mean_time_s")


# ---------------------------------------------------------------------------------------------- import errors

TRIALS_HEADER = "subject,condition,location,attempt,hit,time_s\n"
GOOD = "S1,A,P1,1,1,10.0\n"


@pytest.mark.parametrize("body,pattern", [
    (TRIALS_HEADER + GOOD + "S1,A,P1,2,1,10.0\nS1,A,P1,3,maybe,10.0\n",
     r"data row 3 \(line 4\), column 'hit': expected 1/0 .* got 'maybe'"),
    ("# comment\n\n" + TRIALS_HEADER + GOOD + "S1,A,P1,2,1,-3\n",
     r"data row 2 \(line 5\), column 'time_s': expected > 0, got '-3'"),
    (TRIALS_HEADER + GOOD + "S1,A,P1,1.5,1,10.0\n", r"data row 2 \(line 3\), column 'attempt': expected an integer"),
    (TRIALS_HEADER + GOOD + "S1,A,P1,0,1,10.0\n", r"data row 2 \(line 3\), column 'attempt': expected >= 1"),
    (TRIALS_HEADER + GOOD + "S1,A,P1,2,1,ten\n", r"data row 2 \(line 3\), column 'time_s': expected a number"),
    (TRIALS_HEADER + GOOD + ",A,P1,2,1,10\n", r"data row 2 \(line 3\), column 'subject': value required"),
    (TRIALS_HEADER + GOOD + "S1,A,P1,2,1\n", r"data row 2 \(line 3\): expected 6 fields .* got 5"),
    (TRIALS_HEADER + GOOD + "S1,A,P1,2,1,9\nS1,A,P1,1,0,8\n",
     r"data row 3 \(line 4\): duplicate of data row 1 \(subject='S1', condition='A', location='P1', attempt='1'\)"),
    ("subject,condition,location,attempt,hit\n" + "S1,A,P1,1,1\n", r"missing column\(s\) \['time_s'\]"),
    (TRIALS_HEADER.strip() + ",operator\n" + "S1,A,P1,1,1,10,me\n", r"unknown column\(s\) \['operator'\]"),
    ("subject,location,condition,hit_pct\n1,P1,a,50\n", r"exactly one unit column"),
    ("subject,condition,mean_time\n1,a,5\n", r"unknown column\(s\) \['mean_time'\]"),
    ("subject,condition,hit_pct\n1,a,50\n1,b,120\n", r"data row 2 \(line 3\), column 'hit_pct': expected <= 100"),
    ("subject,condition,hits,attempts\n1,a,5,8\n1,b,9,8\n", r"data row 2 \(line 3\), column 'hits': 9 hits > 8"),
    ("subject,condition,hits,attempts\n1,a,5,\n", r"data row 1 \(line 2\), column 'attempts': value required"),
    ("subject,condition,hits\n1,a,5\n", r"'hits' and 'attempts' go together"),
    ("subject,condition,hits,attempts,hit_pct\n1,a,5,8,62.5\n", r"either 'hits'\+'attempts' or 'hit_pct'"),
    ("subject,condition\n1,a\n", r"no measure column"),
    ("subject,condition,hit_pct\n1,a,50\n2,a,60\n1,a,70\n",
     r"data row 3 \(line 4\): duplicate of data row 1 \(subject='1', condition='a'\)"),
    ("# only a comment\n", r"no header line"),
    ("subject,condition,hit_pct\n", r"header but no data rows"),
    ("subject,,hit_pct\n1,a,5\n", r"empty column name"),
])
def test_import_errors_name_row_and_column(tmp_path: Path, body: str, pattern: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(DataFormatError, match=pattern) as info:
        read_hmi_csv(path)
    assert str(path) in str(info.value)


def test_import_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="no such file"):
        read_hmi_csv(tmp_path / "absent.csv")


def test_analyse_with_too_few_complete_units(tmp_path: Path) -> None:
    path = tmp_path / "s.csv"
    path.write_text("subject,condition,hit_pct\n1,a,50\n1,b,-\n2,a,60\n2,b,70\n")
    with pytest.raises(DataFormatError, match=r"need at least 2 complete subjects .* 1: missing b: no hit_rate"):
        read_hmi_csv(path).analyse()


# ------------------------------------------------------------------------------------------------- figures


def test_bar_stats_mean_and_median() -> None:
    wide = load("thesis_t6_10_subjects.csv").wide("hit_pct")
    mean = bar_stats(wide, statistic="mean")
    assert mean["n"].tolist() == [9, 8, 8, 9, 8, 8]
    assert mean.loc["E1", "value"] == pytest.approx(442 / 9)
    sem_e2 = wide["E2"].std(ddof=1) / np.sqrt(8)
    assert mean.loc["E2", "upper"] - mean.loc["E2", "value"] == pytest.approx(sem_e2)
    sd = bar_stats(wide, statistic="mean", error="sd")
    assert_printed(sd.loc["E1", "upper"] - sd.loc["E1", "value"], "17.09")  # Table 6.10 'SEM' row (= SD)
    median = bar_stats(wide, statistic="median")
    assert median["value"].tolist() == [50.0, 75.0, 68.5, 62.0, 56.0, 50.0]
    assert median.loc["E1", "lower"] == 37.0 and median.loc["E1", "upper"] == 50.0
    with pytest.raises(ValueError):
        bar_stats(wide, statistic="mode")
    with pytest.raises(ValueError):
        bar_stats(wide, statistic="median", error="sem")


@pytest.mark.parametrize("statistic", ["mean", "median"])
def test_bar_chart_png_written(tmp_path: Path, statistic: str) -> None:
    res = load("thesis_t6_10_subjects.csv")
    out = save_bar_chart({"Hits (%)": res.wide("hit_pct"), "Execution time (s)": res.wide("mean_time_s")},
                         tmp_path / f"{statistic}.png", statistic=statistic, dpi=100)
    assert out == tmp_path / f"{statistic}.png"
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(out)
    assert image.shape[:2] == (360, 800)  # 2 panels x 4.0 in x 100 dpi, 3.6 in high
    assert image[..., :3].std() > 0.05  # something was drawn

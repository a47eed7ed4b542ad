"""Tests of wamctl.analysis.anova against the ANOVA tables printed in thesis chapter 6.

Fixtures (tests/fixtures/hmi/) hold the per-location and per-subject values printed in Tables 6.2-6.4, 6.8 and
6.10, and the printed ANOVA tables 6.5, 6.6, 6.9 and 6.11 (thesis_printed.yaml). Nothing is read from ../shared.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import linalg, stats

from wamctl.analysis.anova import cells, oneway, posthoc, repeated

FIXTURES = Path(__file__).parents[1] / "fixtures" / "hmi"
PRINTED = yaml.safe_load((FIXTURES / "thesis_printed.yaml").read_text())

# Issue 8 (not printed in the thesis): RM-ANOVA of hits on the 8 complete subjects of Table 6.10.
RM_HITS_F, RM_HITS_DF, RM_HITS_P = "3.04", (5, 35), "0.022"


def assert_printed(value: float, printed: str, what: str = "") -> None:
    """``value`` rounds to ``printed`` at its printed precision (half a unit of the last printed digit)."""
    decimals = len(printed.split(".")[1]) if "." in printed else 0
    tol = 0.5 * 10.0 ** -decimals + 1e-12
    assert abs(value - float(printed)) <= tol, f"{what}: computed {value!r}, printed {printed}"


def load_long(name: str) -> pd.DataFrame:
    """Fixture CSV as long data frame, hit percentage converted to proportion (as the thesis ANOVA uses)."""
    frame = pd.read_csv(FIXTURES / name, comment="#", na_values=["-"], dtype={"subject": str, "location": str})
    frame["hit_rate"] = frame["hit_pct"] / 100.0
    return frame


def unit_of(frame: pd.DataFrame) -> str:
    return "subject" if "subject" in frame.columns else "location"


def groups_of(frame: pd.DataFrame, measure: str) -> dict[str, np.ndarray]:
    levels = list(pd.unique(frame["condition"]))
    return {c: frame.loc[frame["condition"] == c, measure].to_numpy(float) for c in levels}


def complete(frame: pd.DataFrame) -> cells.CompleteCases:
    return cells.complete_cases(frame, unit=unit_of(frame), condition="condition",
                                values=["hit_rate", "mean_time_s"])


TABLE_CASES = [(t, m) for t in ("table_6_5", "table_6_6", "table_6_9", "table_6_11")
               for m in ("hit_rate", "mean_time_s")]


# ------------------------------------------------------------------------------------------------ one-way, raw


@pytest.mark.parametrize("table,measure", TABLE_CASES)
def test_one_way_reproduces_printed_table(table: str, measure: str) -> None:
    printed = PRINTED["anova"][table]
    cc = complete(load_long(printed["fixture"]))
    result = oneway.one_way_anova(groups_of(cc.data, measure), dv=measure)
    exp = printed[measure]
    for line, row in (("between", result.between), ("within", result.within), ("total", result.total)):
        assert row.df == exp[line]["df"], f"{table} {measure} {line} df"
        assert_printed(row.ss, exp[line]["ss"], f"{table} {measure} {line} SS")
        if "ms" in exp[line]:
            assert_printed(row.ms, exp[line]["ms"], f"{table} {measure} {line} MS")
    assert_printed(result.f, exp["between"]["f"], f"{table} {measure} F")
    assert_printed(result.p, exp["between"]["p"], f"{table} {measure} p")
    assert result.total.ms is None and result.within.f is None
    assert result.input_form == "raw"


def test_table_6_11_needs_the_complete_subjects() -> None:
    """All nine subjects (subject 9 only in E1, E4) give F(5, 44), not the printed F(5, 42) = 2.86."""
    frame = load_long("thesis_t6_10_subjects.csv")
    available = {c: v[np.isfinite(v)] for c, v in groups_of(frame, "hit_rate").items()}
    all_nine = oneway.one_way_anova(available, dv="hit_rate")
    assert all_nine.df == (5, 44)
    assert round(all_nine.f, 2) != 2.86
    eight = oneway.one_way_anova(groups_of(complete(frame).data, "hit_rate"), dv="hit_rate")
    assert eight.df == (5, 42)
    assert eight.apa() == "F(5, 42) = 2.86, p = 0.0262"


def test_one_way_matches_scipy_and_partition() -> None:
    frame = load_long("thesis_t6_2_t6_3_filters.csv")
    g = groups_of(frame, "mean_time_s")
    result = oneway.one_way_anova(g)
    ref = stats.f_oneway(*g.values())
    assert result.f == pytest.approx(ref.statistic, rel=1e-12)
    assert result.p == pytest.approx(ref.pvalue, rel=1e-12)
    y = np.concatenate(list(g.values()))
    assert result.total.ss == pytest.approx(np.sum((y - y.mean()) ** 2), rel=1e-12)
    assert result.between.ms / result.within.ms == pytest.approx(result.f, rel=1e-12)


def test_one_way_small_hand_example() -> None:
    # groups {1,2,3} and {4,5,6}: SSB = 2 * 3 * 1.5^2 = 13.5, SSW = 2 + 2 = 4, F = 13.5 / (4 / 4)
    result = oneway.one_way_anova({"a": [1, 2, 3], "b": [4, 5, 6]})
    assert result.between.ss == pytest.approx(13.5)
    assert result.within.ss == pytest.approx(4.0)
    assert result.df == (1, 4)
    assert result.f == pytest.approx(13.5)
    assert result.p == pytest.approx(stats.f.sf(13.5, 1, 4))


def test_one_way_rejects_nan_and_bad_shapes() -> None:
    with pytest.raises(ValueError, match="complete_cases"):
        oneway.one_way_anova({"a": [1.0, np.nan], "b": [1.0, 2.0]})
    with pytest.raises(ValueError, match="at least 2 groups"):
        oneway.one_way_anova({"a": [1.0, 2.0]})
    with pytest.raises(ValueError, match="no observations"):
        oneway.one_way_anova({"a": [1.0, 2.0], "b": []})
    with pytest.raises(ValueError, match="more observations"):
        oneway.one_way_anova({"a": [1.0], "b": [2.0]})


# -------------------------------------------------------------------------------------------- one-way, summary


@pytest.mark.parametrize("table,measure", TABLE_CASES)
def test_summary_form_equals_raw_form(table: str, measure: str) -> None:
    cc = complete(load_long(PRINTED["anova"][table]["fixture"]))
    raw = oneway.one_way_anova(groups_of(cc.data, measure), dv=measure)
    summary = raw.group_stats()
    from_sd = oneway.one_way_anova_from_summary(summary, dv=measure)
    sem = summary.assign(sem=summary["sd"] / np.sqrt(summary["n"])).drop(columns="sd")
    from_sem = oneway.one_way_anova_from_summary(sem, dv=measure)
    for res in (from_sd, from_sem):
        assert res.input_form == "summary"
        assert res.df == raw.df
        for a, b in ((res.between, raw.between), (res.within, raw.within), (res.total, raw.total)):
            assert a.ss == pytest.approx(b.ss, rel=1e-10)
        assert res.f == pytest.approx(raw.f, rel=1e-10)
        assert res.p == pytest.approx(raw.p, rel=1e-9)


def test_summary_form_from_printed_rows_is_only_approximate() -> None:
    """Table 6.6, hits, from the printed Average and 'SEM' (= SD) rows of Table 6.4: right to ~2 digits only."""
    rows = PRINTED["summary_rows"]["table_6_4_hits"]
    summary = pd.DataFrame({"n": 8, "mean": [float(v) / 100 for v in rows["average"]],
                            "sd": [float(v) / 100 for v in rows["sem_row"]]}, index=rows["conditions"])
    res = oneway.one_way_anova_from_summary(summary, dv="hit_rate")
    exp = PRINTED["anova"]["table_6_6"]["hit_rate"]
    assert res.df == (2, 21)
    assert_printed(res.f, exp["between"]["f"], "F")  # 2.279 -> 2.28
    assert res.p == pytest.approx(float(exp["between"]["p"]), abs=5e-4)  # 0.1271 vs printed 0.1272
    assert res.within.ss != pytest.approx(float(exp["within"]["ss"]), abs=5e-6)  # 0.47600 vs printed 0.47625


def test_summary_form_validation() -> None:
    with pytest.raises(ValueError, match="'sd' or a 'sem'"):
        oneway.one_way_anova_from_summary(pd.DataFrame({"n": [3, 3], "mean": [1.0, 2.0]}, index=["a", "b"]))
    with pytest.raises(ValueError, match="positive integers"):
        oneway.one_way_anova_from_summary(pd.DataFrame({"n": [0, 3], "mean": [1.0, 2.0], "sd": [1.0, 1.0]}))
    with pytest.raises(ValueError, match="missing column"):
        oneway.one_way_anova_from_summary(pd.DataFrame({"mean": [1.0, 2.0], "sd": [1.0, 1.0]}))


# ------------------------------------------------------------------------------------------------ missing cells


def test_complete_cases_reports_subject_9() -> None:
    frame = load_long("thesis_t6_10_subjects.csv")
    cc = complete(frame)
    assert cc.units == tuple(str(i) for i in range(1, 9))
    assert cc.levels == ("E1", "E2", "E3", "E4", "E5", "E6")
    assert [tuple(e) for e in cc.exclusions] == [
        ("9", "missing E2: no data; E3: no data; E5: no data; E6: no data")]
    assert len(cc.data) == 48
    assert cc.to_pandas().to_dict("records") == [
        {"unit": "9", "reason": "missing E2: no data; E3: no data; E5: no data; E6: no data"}]
    assert json.loads(json.dumps(cc.to_dict(), allow_nan=False))["exclusions"][0]["unit"] == "9"


def test_complete_cases_absent_rows_and_single_missing_value() -> None:
    frame = pd.DataFrame({
        "subject": ["a", "a", "b", "c", "c"],
        "condition": ["x", "y", "x", "x", "y"],
        "hit_rate": [0.5, 0.6, 0.7, 0.8, 0.9],
        "mean_time_s": [10.0, 11.0, 12.0, 13.0, np.nan],
    })
    cc = cells.complete_cases(frame, unit="subject", condition="condition", values=["hit_rate", "mean_time_s"])
    assert cc.units == ("a",)
    assert list(cc.exclusions) == [("b", "missing y: no data"), ("c", "missing y: no mean_time_s")]
    only_hits = cells.complete_cases(frame, unit="subject", condition="condition", values=["hit_rate"])
    assert only_hits.units == ("a", "c")
    with pytest.raises(ValueError, match="duplicate"):
        cells.complete_cases(pd.concat([frame, frame.iloc[:1]]), unit="subject", condition="condition",
                             values=["hit_rate"])


# ----------------------------------------------------------------------------------------- repeated measures


def mauchly_reference(y: np.ndarray) -> dict[str, float]:
    """Independent Mauchly test and epsilons (orthonormal contrasts), n units x k conditions."""
    n, k = y.shape
    m = linalg.null_space(np.ones((1, k)))  # k x (k - 1), orthonormal, orthogonal to the grand mean
    s = np.cov(y @ m, rowvar=False)
    p = k - 1
    w = np.linalg.det(s) / (np.trace(s) / p) ** p
    rho = 1 - (2 * p * p + p + 2) / (6 * p * (n - 1))
    chi2 = -(n - 1) * rho * math.log(w)
    dof = p * (p + 1) // 2 - 1
    # second-order p value as R's mauchly.test (Anderson 2003), whose w2 term uses k (the number of conditions)
    w2 = (p + 2) * (p - 1) * (p - 2) * (2 * p ** 3 + 6 * p ** 2 + 3 * k + 2) / (288 * ((n - 1) * p * rho) ** 2)
    p1, p2 = stats.chi2.sf(chi2, dof), stats.chi2.sf(chi2, dof + 4)
    eps_gg = np.trace(s) ** 2 / (p * np.trace(s @ s))
    eps_hf = min(1.0, (n * p * eps_gg - 2) / (p * (n - 1 - p * eps_gg)))
    return {"W": w, "chi2": chi2, "dof": dof, "p": p1 + w2 * (p2 - p1), "eps_gg": eps_gg, "eps_hf": eps_hf}


@pytest.fixture(scope="module")
def table_6_10_complete() -> pd.DataFrame:
    return complete(load_long("thesis_t6_10_subjects.csv")).data


def test_rm_anova_hits_issue_8(table_6_10_complete: pd.DataFrame) -> None:
    res = repeated.rm_anova(table_6_10_complete, dv="hit_rate", within="condition", subject="subject")
    assert res.df == RM_HITS_DF
    assert_printed(res.f, RM_HITS_F, "RM F")
    assert_printed(res.p, RM_HITS_P, "RM p")
    assert res.levels == ("E1", "E2", "E3", "E4", "E5", "E6") and len(res.units) == 8
    # same condition SS as the one-way table 6.11; error = within - subjects
    assert_printed(res.effect.ss, PRINTED["anova"]["table_6_11"]["hit_rate"]["between"]["ss"])
    assert res.effect.ss + res.subjects.ss + res.error.ss == pytest.approx(res.total.ss, rel=1e-12)
    assert_printed(res.total.ss, PRINTED["anova"]["table_6_11"]["hit_rate"]["total"]["ss"])
    assert res.subjects.df == 7 and res.total.df == 47
    # sphericity: values from an independent implementation
    ref = mauchly_reference(table_6_10_complete.pivot(index="subject", columns="condition",
                                                      values="hit_rate").to_numpy(float))
    s = res.sphericity
    assert s.w == pytest.approx(ref["W"], rel=1e-9)
    assert s.chi2 == pytest.approx(ref["chi2"], rel=1e-9)
    assert s.dof == ref["dof"] == 14
    assert s.p == pytest.approx(ref["p"], rel=1e-9)
    assert s.eps_gg == pytest.approx(ref["eps_gg"], rel=1e-9)
    assert s.eps_hf == pytest.approx(ref["eps_hf"], rel=1e-9)
    assert s.eps_lb == pytest.approx(0.2)
    assert s.assumed()  # Mauchly p = 0.78
    assert round(s.eps_gg, 3) == 0.643
    assert s.p_gg == pytest.approx(stats.f.sf(res.f, 5 * s.eps_gg, 35 * s.eps_gg), rel=1e-12)
    assert round(s.p_gg, 3) == 0.047
    assert s.p_hf == pytest.approx(res.p)  # HF epsilon capped at 1
    assert res.apa() == ("F(5, 35) = 3.04, p = 0.022 (GG eps = 0.643, p = 0.047; Mauchly W = 0.135, p = 0.779)")


def test_rm_anova_time_sphericity_violated(table_6_10_complete: pd.DataFrame) -> None:
    res = repeated.rm_anova(table_6_10_complete, dv="mean_time_s", within="condition", subject="subject")
    ref = mauchly_reference(table_6_10_complete.pivot(index="subject", columns="condition",
                                                      values="mean_time_s").to_numpy(float))
    assert res.df == (5, 35)
    assert round(res.f, 2) == 2.55 and round(res.p, 3) == 0.045
    assert res.sphericity.p == pytest.approx(ref["p"], rel=1e-9)
    assert not res.sphericity.assumed()  # Mauchly p = 0.035
    assert res.sphericity.eps_gg == pytest.approx(ref["eps_gg"], rel=1e-9)
    assert res.sphericity.eps_hf == pytest.approx(ref["eps_hf"], rel=1e-9)
    assert round(res.sphericity.p_gg, 3) == 0.119


@pytest.mark.parametrize("dv", ["hit_rate", "mean_time_s"])
def test_rm_anova_cross_check_statsmodels(table_6_10_complete: pd.DataFrame, dv: str) -> None:
    from statsmodels.stats.anova import AnovaRM

    ref = AnovaRM(table_6_10_complete, dv, "subject", within=["condition"]).fit().anova_table
    res = repeated.rm_anova(table_6_10_complete, dv=dv, within="condition", subject="subject")
    assert res.f == pytest.approx(ref.loc["condition", "F Value"], rel=1e-9)
    assert res.p == pytest.approx(ref.loc["condition", "Pr > F"], rel=1e-9)
    assert res.df == (int(ref.loc["condition", "Num DF"]), int(ref.loc["condition", "Den DF"]))


def test_rm_anova_needs_complete_data() -> None:
    frame = load_long("thesis_t6_10_subjects.csv")
    with pytest.raises(ValueError, match=r"incomplete units: 9 \(missing E2"):
        repeated.rm_anova(frame, dv="hit_rate", within="condition", subject="subject")


def test_rm_anova_two_conditions_equals_paired_t() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=6), rng.normal(size=6) + 0.8
    frame = pd.DataFrame({"s": np.tile(np.arange(6).astype(str), 2), "c": ["a"] * 6 + ["b"] * 6,
                          "y": np.concatenate([a, b])})
    res = repeated.rm_anova(frame, dv="y", within="c", subject="s")
    t = stats.ttest_rel(a, b)
    assert res.f == pytest.approx(t.statistic ** 2, rel=1e-9)
    assert res.p == pytest.approx(t.pvalue, rel=1e-9)
    assert res.sphericity.w == 1.0 and res.sphericity.p_gg == pytest.approx(res.p)


def test_rm_anova_to_dict_and_pandas(table_6_10_complete: pd.DataFrame) -> None:
    res = repeated.rm_anova(table_6_10_complete, dv="hit_rate", within="condition", subject="subject")
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["F"] == pytest.approx(res.f) and d["df_error"] == 35
    assert d["sphericity"]["eps_gg"] == pytest.approx(res.sphericity.eps_gg)
    assert d["sphericity"]["sphericity_assumed"] is True
    assert [r["source"] for r in d["table"]] == ["condition", "Subjects", "Error", "Total"]
    table = res.to_pandas()
    assert list(table.index) == ["condition", "Subjects", "Error", "Total"]
    assert table.loc["condition", "p_GG"] == pytest.approx(res.sphericity.p_gg)


def test_one_way_to_dict_and_pandas() -> None:
    cc = complete(load_long("thesis_t6_10_subjects.csv"))
    res = oneway.one_way_anova(groups_of(cc.data, "hit_rate"), dv="hit_rate")
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["table"][0] == {"source": "Between Groups", "ss": pytest.approx(0.373641666), "df": 5,
                             "ms": pytest.approx(0.074728333), "F": pytest.approx(res.f), "p": pytest.approx(res.p)}
    assert d["table"][2]["ms"] is None and d["table"][2]["F"] is None
    assert [g["n"] for g in d["groups"]] == [8] * 6
    table = res.to_pandas()
    assert list(table.index) == ["Between Groups", "Within Groups", "Total"]
    assert list(table.columns) == ["SS", "df", "MS", "F", "p"]
    assert np.isnan(table.loc["Total", "MS"])


# ------------------------------------------------------------------------------------------------ pairwise


def test_pairwise_holm_table_6_10(table_6_10_complete: pd.DataFrame) -> None:
    from statsmodels.stats.multitest import multipletests

    res = posthoc.pairwise_paired_t(table_6_10_complete, dv="hit_rate", within="condition", subject="subject")
    wide = table_6_10_complete.pivot(index="subject", columns="condition", values="hit_rate")
    assert len(res.comparisons) == 15
    assert [(c.a, c.b) for c in res.comparisons[:3]] == [("E1", "E2"), ("E1", "E3"), ("E1", "E4")]
    p_unc = []
    for c in res.comparisons:
        ref = stats.ttest_rel(wide[c.a], wide[c.b])
        assert c.t == pytest.approx(ref.statistic, rel=1e-9)
        assert c.p_unc == pytest.approx(ref.pvalue, rel=1e-9)
        assert c.mean_diff == pytest.approx((wide[c.a] - wide[c.b]).mean())
        assert c.n == 8 and c.dof == 7
        p_unc.append(c.p_unc)
    holm = multipletests(p_unc, method="holm")[1]
    assert [c.p_holm for c in res.comparisons] == pytest.approx(list(holm), rel=1e-9)
    e2_e6 = next(c for c in res.comparisons if (c.a, c.b) == ("E2", "E6"))
    assert round(e2_e6.t, 3) == 3.432 and round(e2_e6.p_unc, 4) == 0.011 and round(e2_e6.p_holm, 3) == 0.164
    assert min(c.p_holm for c in res.comparisons) > 0.05  # no pair survives Holm
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["p_adjust"] == "holm" and len(d["comparisons"]) == 15


def test_pairwise_keeps_input_order_and_sign() -> None:
    rng = np.random.default_rng(2)
    levels = ["z", "b", "a"]  # not alphabetical
    y = {c: rng.normal(size=5) + i for i, c in enumerate(levels)}
    frame = pd.DataFrame([(str(s), c, y[c][s]) for c in levels for s in range(5)], columns=["s", "c", "y"])
    res = posthoc.pairwise_paired_t(frame, dv="y", within="c", subject="s")
    assert [(c.a, c.b) for c in res.comparisons] == [("z", "b"), ("z", "a"), ("b", "a")]
    for c in res.comparisons:
        assert c.t == pytest.approx(stats.ttest_rel(y[c.a], y[c.b]).statistic, rel=1e-9)

"""What each command prints on an 80-column terminal: lines that fit, tables whose every cell arrives whole (no
number or word cut, the key column in every part of a split table), the same numbers as the report files, tiny
values in scientific notation, and --help that wraps cleanly with plain flags (no ``<bool>``).

The commands run in-process at COLUMNS=80 (tests/cli_runs.py, one small run of every kind per session)."""

from __future__ import annotations

import json
import re

import pytest
from cli_runs import run_cli

WIDTH = 80
# the command printing each run's tables, and the report whose tables it prints (all of them, or the first n)
PRINTED = {"run": ("rotation", None), "friction-id": ("friction_sweep", None), "tune-ift": ("ift", None),
           "hmi-session": ("hmi_block", None), "diagnose": ("diagnosis", ("summary", "effects"))}


def markdown_tables(md: str) -> list[list[list[str]]]:
    """Every pipe table of a Markdown report: rows (header first) of cell texts, the separator row dropped."""
    tables, cur = [], []
    for line in md.splitlines() + [""]:
        if line.startswith("|"):
            cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                cur.append(cells)
        elif cur:
            tables.append(cur)
            cur = []
    return tables


def report_tables(run_dir, names=None) -> dict[str, list[list[str]]]:
    """The tables of a run's report.md by name (names from report.json, in the same order)."""
    md = markdown_tables((run_dir / "report.md").read_text())
    keys = list(json.loads((run_dir / "report.json").read_text())["tables"])
    assert len(md) == len(keys)
    tables = dict(zip(keys, md))
    return {k: v for k, v in tables.items() if names is None or k in names}


def check_width(out: str, label: str) -> None:
    """Every line fits, but for a status line ending in a long path, printed unwrapped so that it can be
    copied (the terminal wraps it)."""
    for line in out.splitlines():
        if len(line) > WIDTH:
            assert "/" in line.split()[-1] and len(line.split()[-1]) > 30, f"{label}: {len(line)} columns: {line!r}"


def tokens(text: str) -> set[str]:
    return set(text.split())


def check_cells_whole(printed: str, table: list[list[str]], where: str) -> None:
    """Every word of every cell (numbers are one word) is a whole token of the terminal output; empty cells of
    the report are ``-`` there."""
    have = tokens(printed)
    for row in table[1:]:
        for cell in row:
            for word in cell.split():
                assert word in have, f"{where}: {word!r} is not printed whole"


@pytest.mark.parametrize("label", sorted(PRINTED))
def test_every_table_fits_80_columns_and_keeps_each_cell_whole(small_runs, label):
    r = small_runs.printed[label]
    kind, names = PRINTED[label]
    check_width(r.out, label)
    tables = report_tables(small_runs.runs[kind], names)
    assert tables
    for name, table in tables.items():
        assert f": {name}" in r.out, f"{label}: table {name} not printed"
        check_cells_whole(r.out, table, f"{label} {name}")
    assert "nan" not in tokens(r.out.lower())


def test_a_split_table_repeats_its_key_column_in_every_part(small_runs):
    out = small_runs.printed["tune-ift"].out
    block = out.split(": comparison_rpe\n")[1].split("\n\n")[0]   # 10 columns: more than 80 characters
    lines = block.splitlines()
    marks = [i for i, ln in enumerate(lines) if re.fullmatch(r"\s*\(\d/\d\)\s*", ln)]
    assert len(marks) >= 2, block
    for start, end in zip(marks, marks[1:] + [len(lines)]):
        part = lines[start:end]
        rule = next(i for i, ln in enumerate(part) if set(ln.strip()) == {"─"})
        assert "joint" in " ".join(part[1:rule]).split()                # the key column's header
        assert [ln.split()[0] for ln in part[rule + 1:] if ln.strip()][:1] == ["7"]   # and its value


def test_tiny_values_are_in_scientific_notation(small_runs):
    out = small_runs.printed["tune-ift"].out
    block = out.split(": ift_J")[1].split("\n\n")[0]
    rows = [ln.split() for ln in block.splitlines() if re.match(r"^\d+\s", ln)]
    assert rows and all(re.fullmatch(r"\d\.\d{3}e-\d\d", c) for row in rows for c in row[1:]), block


def test_ift_gains_at_their_bounds_are_flagged_on_the_terminal(small_runs):
    out = " ".join(small_runs.printed["tune-ift"].out.split())
    assert ("warning: J still fell at the upper bound of kp (joint 7), kd (7): the bound, not J, chose these gains "
            "(see ift.bounds).") in out


def test_combined_report_command_prints_whole_cells(small_runs):
    r = small_runs.printed["report"]
    check_width(r.out, "report")
    combined = markdown_tables((small_runs.reports["combined"].with_suffix(".md")).read_text())
    for table in combined:
        check_cells_whole(r.out, [[re.sub(r"\[(.*)\]\(.*\)", r"\1", c) for c in row] for row in table], "combined")
    assert "nan" not in tokens(r.out.lower())


@pytest.mark.parametrize("label", ["bus-check", "sweep --dry-run", "report --hmi-results"])
def test_other_tables_fit_80_columns(small_runs, label):
    r = small_runs.printed[label]
    assert r.out.strip()
    check_width(r.out, label)
    if label == "bus-check":
        rows = [ln.split() for ln in r.out.splitlines() if re.match(r"^[1-7]\s+motor", ln)]
        assert [row[-1] for row in rows] == [str(1000 + j) for j in range(1, 8)]   # SN: the last column, whole


COMMANDS = ["run", "validate", "report", "export", "import", "friction-id", "diagnose", "tune-ift", "hmi-session",
            "bus-check", "sweep"]


@pytest.mark.parametrize("cmd", [None, *COMMANDS])
def test_help_wraps_at_80_columns_without_bool_metavars(cmd):
    r = run_cli(*([cmd] if cmd else []), "--help")
    assert r.code == 0 and r.exc is None, r.tb
    lines = r.out.splitlines()
    assert len(lines) > 8
    assert all(len(ln) <= WIDTH for ln in lines), [ln for ln in lines if len(ln) > WIDTH]
    assert "<bool>" not in r.out and "--help" in r.out
    if cmd is None:   # the command list: every command with its first sentence, none cut at 45 characters
        assert "friction-id  Identify joint friction (thesis ch. 4)" in r.out
        assert "..." not in r.out.split("Commands:")[1]


def test_an_operator_countdown_fits_the_bar_line_at_80_columns():
    """The countdown shows in the progress bar's line, whose text a terminal of 80 columns cut after 48 characters
    ("Move the arm by hand to the run's start pose: joint 2 is at 0.310 rad, the run st… …"): the joint and both
    numbers now survive; the whole message is printed above the bar once."""
    from wamctl.backends.can.operator import short_message

    width = 80 - 32   # the bar, its percentage and times, and the seconds left take 32 columns
    start = ("Move the arm by hand to the run's start pose: joint 2 at 0.310 rad, to 0.000 rad (the run starts "
             "within 0.02 rad of it on every joint; the arm is idle)")
    assert short_message(start, width) == "joint 2 at 0.310 rad, to 0.000 rad"
    assert short_message("Press Shift-Activate on the pendant", width) == "Press Shift-Activate on the pendant"
    idle = "Press Shift-Idle on the pendant (the pucks are idle; the safety module is still active)"
    assert short_message(idle, width) == "Press Shift-Idle on the pendant"
    long = short_message("x" * 200, width)
    assert len(long) == width and long.endswith("\u2026")

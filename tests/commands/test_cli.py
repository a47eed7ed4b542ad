"""The lab's daily loop through the real command line: specs, run directories, reports, bad input, Ctrl-C.

The commands run in this process (``wamctl.cli.main``, as tests/cli_runs.py runs them), but for the two whose
subject is the process: an error on a stderr that is not a terminal, and a run killed by a signal."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from conftest import rotation_spec

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


def wamctl(*args) -> subprocess.CompletedProcess:
    """``wamctl ARGS`` in this process at 80 columns (tests/cli_runs.py: ``main()``, its exit code, stdout and
    stderr; an exception escaping ``main()`` comes back as the traceback a user would see on stderr). Each of the
    50-odd commands of this file had started a Python of its own (about 2.5 s of imports each, a minute of CPU
    in all); the real process is kept where it is the subject: stderr that is not a terminal, and the killed run."""
    r = run_cli(*args, columns=80)
    return subprocess.CompletedProcess(["wamctl", *map(str, args)], r.code, r.out, r.err + r.tb)


def wamctl_process(*args, timeout=300) -> subprocess.CompletedProcess:
    """``python -m wamctl ARGS`` in a process of its own."""
    return subprocess.run([sys.executable, "-m", "wamctl", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def write(path: Path, obj) -> Path:
    path.write_text(obj if isinstance(obj, str) else yaml.safe_dump(obj))
    return path


def only_run_dir(runs: Path) -> Path:
    dirs = [d for d in runs.iterdir() if d.is_dir()]
    assert len(dirs) == 1, dirs
    return dirs[0]


# ------------------------------------------------------------------------------ examples and the happy path
TEMPLATES = {"hmi_block_replay_raw.yaml": "hmi.source.path"}    # a path the user fills in (a run's capture)


@pytest.mark.parametrize("config", CONFIGS, ids=[c.name for c in CONFIGS])
def test_example_configs_validate(config, tmp_path):
    r = wamctl("validate", config)
    if config.name not in TEMPLATES:
        assert r.returncode == 0, r.stderr
        assert "valid" in r.stdout
        return
    # a template: refused before anything runs, naming the field to fill in; valid once it names a file
    assert r.returncode == 2 and r.stderr.startswith(f"error: {TEMPLATES[config.name]}: no file"), r.stderr
    assert "Traceback" not in r.stderr
    raw = yaml.safe_load(config.read_text())
    capture = write(tmp_path / "gaze_capture.txt", "")
    raw["hmi"]["source"]["path"] = str(capture)
    r = wamctl("validate", write(tmp_path / config.name, raw))
    assert r.returncode == 0 and "valid" in r.stdout, r.stderr


def test_validate_says_what_unset_gains_stand_for(tmp_path):
    """``kp: null`` in the resolved spec means libbarrett's gains: validate prints them beside it (and the text
    still reads back as the same spec)."""
    spec = write(tmp_path / "rot.yaml", rotation_spec(controller={"kind": "pd_g", "kd": [5.0] * 7}))
    r = wamctl("validate", spec)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "  kp: null  # libbarrett's: [900.0, 2500.0, 600.0, 500.0, 50.0, 50.0, 8.0]" in lines
    assert "  ki: null  # not used by pd_g" in lines
    kd = next(line for line in lines if line.startswith("  kd:"))
    assert "#" not in kd
    body = r.stdout[:r.stdout.index("\nok ")]          # the spec, then one "ok ..." line per check
    assert yaml.safe_load(body)["controller"]["kp"] is None


@pytest.mark.parametrize("cmd", [("diagnose",), ("identify",)])
def test_an_error_is_the_first_line_when_stderr_is_not_a_terminal(cmd, tmp_path):
    """A log file (stderr not a terminal) gets no progress bar, and so not the blank line it left on stopping
    before the error."""
    r = wamctl_process(*cmd, tmp_path / "nowhere")
    assert r.returncode == 2 and r.stderr.startswith("error: "), repr(r.stderr)


def test_rotation_run_writes_a_self_describing_run_directory(tmp_path, runs_dir):
    spec = write(tmp_path / "rot.yaml", rotation_spec(rotation={"joints": [1, 7], "mode": "one_at_a_time"}))
    r = wamctl("run", spec, "--out", runs_dir, "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    run = Path(out["run_dir"])
    assert run.parent == runs_dir and run.name.endswith("-t")
    m = json.loads((run / "manifest.json").read_text())
    assert m["status"] == "completed" and m["seed"] == 3 and m["kind"] == "rotation"
    assert m["versions"]["pin"] and m["versions"]["numpy"] and m["backend"]["name"] == "sim"
    assert m["start_utc"] < m["end_utc"]
    resolved = yaml.safe_load((run / "spec.yaml").read_text())
    assert resolved["controller"]["kind"] == "pd_g" and resolved["backend"]["physics_substeps"] == 2
    data = pd.read_parquet(run / "data.parquet")
    assert len(data) == len(pd.read_csv(run / "data.csv")) > 1000
    assert {"t_s", "q_ref_1_rad", "q_7_rad", "tau_7_Nm"} <= set(data.columns)
    events = pd.read_csv(run / "events.csv")
    assert (events["detail"] == "move joint 7").any()
    for f in ("report.md", "report.html", "report.json", "rotation_errors.png", "rotation_positions.png"):
        assert (run / f).stat().st_size > 0
    rpe = out["report"]["rpe_pct"]
    assert set(rpe) == {"1", "7"}
    assert 0.3 < rpe["1"] < 1.2 and 0.5 < rpe["7"] < 3.5        # friction leaves ~Fc/Kp, as in the thesis
    md = (run / "report.md").read_text()
    assert "thesis_rpe_pct" in md and "1.0876" in md


def test_dry_run_checks_limits_and_moves_nothing(tmp_path, runs_dir):
    spec = write(tmp_path / "rot.yaml", rotation_spec())
    r = wamctl("run", spec, "--out", runs_dir, "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "position setpoints within the joint limits" in r.stdout and "nothing moved" in r.stdout
    assert not any(runs_dir.iterdir())


def test_help_is_useful_on_every_command():
    for cmd in ("run", "validate", "report", "export", "import"):
        r = wamctl(cmd, "--help")
        assert r.returncode == 0 and len(r.stdout) > 300, cmd


# ------------------------------------------------------------------------------ bad input: one line, exit 2
BAD_SPECS = {
    "unknown key": (rotation_spec(colour="red"), "colour = 'red': unknown key"),
    "wrong type": (rotation_spec(seed="abc"), "seed = 'abc': Input should be a valid integer"),
    # the value the spec gave: item 1 of the list (counted from 0, as a sweep's vary names it) is joint 8
    "joint 8": (rotation_spec(rotation={"joints": [1, 8]}), "rotation.joints.1 = 8: Input should be less than"),
    "amplitude outside limits": (rotation_spec(rotation={"amplitude_rad": 2.0}),
                                 "joint 4 would reach 3.5700 rad"),
    "unknown kind": ({"kind": "juggling"}, "kind: 'juggling' unknown"),
}


@pytest.mark.parametrize("name", list(BAD_SPECS))
def test_bad_spec_is_one_line_exit_2(tmp_path, name):
    spec, expected = BAD_SPECS[name]
    path = write(tmp_path / "bad.yaml", spec)
    for cmd in ("validate", "run"):
        r = wamctl(cmd, path)
        assert r.returncode == 2, (cmd, r.stderr)
        assert "Traceback" not in r.stderr
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and expected in lines[0], r.stderr


def test_yaml_syntax_error_names_the_line(tmp_path):
    path = write(tmp_path / "broken.yaml", "kind: rotation\nname: x\nrotation: {joints: [1, 2\nseed: 1\n")
    r = wamctl("run", path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "YAML syntax error at line" in r.stderr


def test_missing_file(tmp_path):
    r = wamctl("run", tmp_path / "nope.yaml")
    assert r.returncode == 2 and "no such file" in r.stderr and "Traceback" not in r.stderr


# ------------------------------------------------------------------------------ measured runs
@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("finished")
    spec = write(tmp / "rot.yaml", rotation_spec(rotation={"joints": [2, 6], "mode": "one_at_a_time",
                                                             "amplitude_rad": -0.5}))
    r = wamctl("run", spec, "--out", tmp / "runs", "--quiet")
    assert r.returncode == 0, r.stderr
    return only_run_dir(tmp / "runs")


def test_export_import_report_gives_the_same_rpe_table(finished_run, tmp_path):
    measured = tmp_path / "measured"
    assert wamctl("export", finished_run, "--to", measured).returncode == 0
    meta = yaml.safe_load((measured / "meta.yaml").read_text())
    assert meta["format"] == "wamctl-measured/1" and meta["experiment"] == {"kind": "rotation", "joints": [2, 6]}
    r = wamctl("import", measured, "--out", tmp_path / "imported")
    assert r.returncode == 0, r.stderr
    imported = only_run_dir(tmp_path / "imported")
    a = wamctl("report", finished_run, "--json", "--out", tmp_path / "ra")
    b = wamctl("report", imported, "--json", "--out", tmp_path / "rb")
    assert a.returncode == 0 and b.returncode == 0, (a.stderr, b.stderr)
    ta = json.loads(a.stdout)["reports"][0]["tables"]["rotation"]
    tb = json.loads(b.stdout)["reports"][0]["tables"]["rotation"]
    assert ta == tb and len(ta) == 2


def test_export_csv_roundtrip(finished_run, tmp_path):
    assert wamctl("export", finished_run, "--to", tmp_path / "m", "--csv").returncode == 0
    df = pd.read_csv(tmp_path / "m" / "data.csv")
    assert list(df.columns[:2]) == ["t", "q_ref_1"] and "tau_7" in df


@pytest.mark.parametrize("damage,expected", [
    ("drop_column", "missing column(s): q_3"),
    ("non_monotonic", "t is not strictly increasing at data row 100"),   # df row 99 = data row 100
    ("bad_meta", "meta.yaml: controller.kp: List should have at least 7 items"),
    ("missing_meta_key", "meta.yaml: sample_rate_hz: missing"),
    ("wrong_rate", "sample_rate_hz is 250 but t says 500.0 Hz"),
])
def test_bad_measured_run_is_one_line_exit_2(finished_run, tmp_path, damage, expected):
    m = tmp_path / "m"
    assert wamctl("export", finished_run, "--to", m, "--csv").returncode == 0
    df = pd.read_csv(m / "data.csv")
    meta = yaml.safe_load((m / "meta.yaml").read_text())
    if damage == "drop_column":
        df = df.drop(columns=["q_3"])
    elif damage == "non_monotonic":
        df.loc[99, "t"] = df.loc[98, "t"]
    elif damage == "bad_meta":
        meta["controller"]["kp"] = [1, 2]
    elif damage == "missing_meta_key":
        del meta["sample_rate_hz"]
    elif damage == "wrong_rate":
        meta["sample_rate_hz"] = 250
    df.to_csv(m / "data.csv", index=False)
    (m / "meta.yaml").write_text(yaml.safe_dump(meta))
    r = wamctl("import", m, "--out", tmp_path / "imp")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and expected in lines[0], r.stderr


def test_isolated_nan_rows_are_dropped_with_a_count(finished_run, tmp_path):
    from wamctl.runs.measured import read_measured
    m = tmp_path / "m"
    assert wamctl("export", finished_run, "--to", m, "--csv").returncode == 0
    df = pd.read_csv(m / "data.csv")
    df.loc[[10, 500], "q_2"] = float("nan")
    df.to_csv(m / "data.csv", index=False)
    rd = read_measured(m)
    assert len(rd.data) == len(df) - 2


# ------------------------------------------------------------------------------ interruption
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_killed_run_keeps_every_chunk_and_says_interrupted(tmp_path, sig):
    # -0.5 rad: joint 2's return from +0.5 rad would need more than its torque limit (refused, issue 32)
    spec = write(tmp_path / "long.yaml", rotation_spec(rotation={"mode": "one_at_a_time", "amplitude_rad": -0.5}))
    runs = tmp_path / "runs"
    # a shell that runs this suite in the background (nohup, CI runners) hands its children SIGINT ignored, and
    # Python then never installs its Ctrl-C handler: the child gets the terminal's default back, as a terminal has
    proc = subprocess.Popen([sys.executable, "-m", "wamctl", "run", str(spec), "--out", str(runs), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    chunk_dir = None
    while time.monotonic() < deadline:
        parts = list(runs.glob("*/data/part-00001.parquet")) if runs.exists() else []
        if parts:
            chunk_dir = parts[0].parent
            break
        time.sleep(0.02)
    assert chunk_dir is not None, proc.communicate()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    run = chunk_dir.parent
    m = json.loads((run / "manifest.json").read_text())
    assert m["status"] == "interrupted" and ("SIG" in m["reason"] or "Ctrl-C" in m["reason"])
    data = pd.read_parquet(run / "data.parquet")
    assert len(data) >= 5000
    assert not chunk_dir.exists()      # the chunks are removed once data.parquet holds their rows (issue 32)
    assert data["t_s"].is_monotonic_increasing
    assert data.notna().all().all()


def test_report_hmi_results_reproduces_table_6_11(tmp_path):
    """Table 6.11 from Table 6.10 (8 complete subjects) and the repeated-measures ANOVA, through the CLI."""
    csv = ROOT / "tests" / "fixtures" / "hmi" / "thesis_t6_10_subjects.csv"
    r = wamctl("report", "--hmi-results", csv, "--out", tmp_path, "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)["reports"][0]
    anova = {row["source"]: row for row in rep["tables"]["thesis_t6_10_subjects_anova_hit_rate"]}
    between = anova["Between Groups"]
    assert (between["df"], anova["Within Groups"]["df"]) == (5, 42)
    assert round(between["F"], 2) == 2.86 and round(between["p"], 4) == 0.0262
    rm = {row["source"]: row for row in rep["tables"]["thesis_t6_10_subjects_rm_anova_hit_rate"]}
    assert round(rm["condition"]["F"], 2) == 3.04 and round(rm["condition"]["p"], 3) == 0.022
    assert rm["Error"]["df"] == 35
    md = (tmp_path / "thesis_t6_10_subjects_report.md").read_text()
    assert "subject 9: missing" in md and "Greenhouse-Geisser" in md
    assert (tmp_path / "thesis_t6_10_subjects_mean.png").stat().st_size > 1000

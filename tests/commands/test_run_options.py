"""The run commands agree on their options (issue 30, item 5): every one has --out, --json and --quiet; --yes
where a session can ask questions (the CAN arm's zeroing: every command that runs a spec on an arm); --resume where
the kind continues in place (ift, hmi_block; `run --resume` for either; a sweep resumes its sweep directory).
--yes reaches the session's operator; `run --resume` of a kind that cannot is refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import typer
import yaml
from cli_runs import FRICTION, IFT, ROTATION, run_cli

from wamctl import cli

RUN_COMMANDS = ("run", "friction-id", "tune-ift", "hmi-session", "sweep")
ASKS = ("run", "friction-id", "tune-ift", "hmi-session")      # a spec that may drive the CAN arm
RESUMES = ("run", "tune-ift", "hmi-session", "sweep")
# sweep has no --yes: its points run on Dask workers with no terminal (`wamctl sweep` refuses a CAN backend);
# friction-id has no --resume: a friction sweep is run again, it does not continue


def options(name: str) -> set[str]:
    cli._register()
    cmd = typer.main.get_command(cli.app).commands[name]
    return {o for p in cmd.params for o in getattr(p, "opts", []) if o.startswith("--")}


@pytest.mark.parametrize("name", RUN_COMMANDS)
def test_every_run_command_has_the_shared_options(name):
    have = options(name)
    assert {"--out", "--json", "--quiet", "--dry-run"} <= have, have
    assert ("--yes" in have) == (name in ASKS), have
    assert ("--resume" in have) == (name in RESUMES), have


@pytest.fixture()
def operators(monkeypatch):
    """The ``yes`` of every terminal operator a command makes."""
    import wamctl.commands.terminal_operator as terminal_operator
    seen = []
    init = terminal_operator.TerminalOperator.__init__

    def spy(self, yes=False, *a, **k):
        seen.append(yes)
        init(self, yes, *a, **k)
    monkeypatch.setattr(terminal_operator.TerminalOperator, "__init__", spy)
    return seen


@pytest.mark.parametrize("command,spec", [("friction-id", FRICTION), ("tune-ift", IFT)])
def test_yes_reaches_the_sessions_operator(tmp_path, operators, command, spec):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(spec))
    r = run_cli(command, p, "--out", tmp_path / "out", "--quiet", "--json", "--yes")
    assert r.code == 0, r.err
    assert operators == [True]
    if command == "tune-ift":                 # and its --resume, through `run --resume` too
        run = json.loads(r.out)["run_dir"]
        for args in (("tune-ift", p, "--resume", run), ("run", p, "--resume", run)):
            operators.clear()
            r = run_cli(*args, "--quiet", "--json", "-y")
            assert r.code == 0, r.err
            assert operators == [True]


def test_run_resume_refuses_a_kind_that_cannot_in_one_line(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(dict(ROTATION, rotation=dict(ROTATION["rotation"], joints=[7]))))
    r = run_cli("run", p, "--out", tmp_path / "out", "--quiet", "--json")
    assert r.code == 0, r.err
    run = Path(json.loads(r.out)["run_dir"])
    r = run_cli("run", "--resume", run)
    assert r.code == 2 and len(r.err.strip().splitlines()) == 1 and "Traceback" not in r.err, r.err
    assert "a rotation run cannot be resumed" in r.err
    r = run_cli("run", "--resume", tmp_path)
    assert r.code == 2 and "no readable manifest.json" in r.err, r.err
    r = run_cli("run")
    assert r.code == 2 and "give a spec" in r.err, r.err


def test_a_sweep_on_the_can_arm_is_refused_before_anything_runs(tmp_path):
    """Why `sweep` has no --yes: its points would run in parallel on Dask workers with no terminal (it was
    accepted: `sweep --dry-run` said '2 valid points')."""
    spec = dict(ROTATION, backend={"kind": "can", "interface": "virtual", "channel": "wamctl-no-sweep"},
                rotation=dict(ROTATION["rotation"], joints=[7]), vary={"grid": {"seed": [0, 1]}, "reports": False})
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(spec))
    for args in (("sweep", p, "--dry-run"), ("sweep", p, "--out", tmp_path / "out"), ("validate", p)):
        r = run_cli(*args)
        assert r.code == 2 and len(r.err.strip().splitlines()) == 1 and "Traceback" not in r.err, (args, r.err)
        assert "backend: kind can in 2 of 2 points" in r.err, r.err
    assert not (tmp_path / "out").exists()

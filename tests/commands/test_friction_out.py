"""`friction-id --out DIR` means one thing (issue 32): the parent of the new run directory, from a spec as from
--data (it used to be the parent with a spec and the folder itself with --data)."""

from __future__ import annotations

import json

import yaml
from cli_runs import FRICTION, run_cli, write_yaml


def test_out_is_the_parent_of_a_new_run_directory_with_a_spec_and_with_data(tmp_path):
    spec = dict(FRICTION, sweep=dict(FRICTION["sweep"], velocities_rad_s=[0.1, 0.3, 1.0]))
    r = run_cli("friction-id", write_yaml(tmp_path / "fs.yaml", spec), "--out", tmp_path / "a", "--quiet")
    assert r.code == 0, r.err
    (made,) = (tmp_path / "a").iterdir()
    for _ in range(2):        # twice into one parent: two run directories beside each other, nothing overwritten
        r = run_cli("friction-id", "--data", made, "--out", tmp_path / "b", "--json")
        assert r.code == 0, r.err
    again = sorted((tmp_path / "b").iterdir())
    assert len(again) == 2 and [p.name for p in (tmp_path / "b").iterdir() if p.is_file()] == []
    assert json.loads(r.out)["run_dir"] == str(again[-1])
    for run in (made, *again):
        assert json.loads((run / "manifest.json").read_text())["kind"] == "friction_sweep"
        assert (run / "friction_model.yaml").is_file() and (run / "report.html").is_file()
    a = yaml.safe_load((made / "friction_model.yaml").read_text())["joints"]
    b = yaml.safe_load((again[0] / "friction_model.yaml").read_text())["joints"]
    assert a.keys() == b.keys() == {7}
    for key in a[7]:
        if isinstance(a[7][key], float):
            assert abs(a[7][key] - b[7][key]) <= 1e-9 * max(1.0, abs(a[7][key])), key
    r = run_cli("report", again[0], "--quiet")           # a run directory like any other
    assert r.code == 0, r.err


def test_help_says_what_out_means():
    r = run_cli("friction-id", "--help", columns=200)
    out = " ".join(r.out.split())
    assert "--out <path> Parent directory of the new directory written (a run directory with a spec or --data" in out


def test_compare_writes_a_new_folder_under_out(tmp_path):
    from cli_runs import ROTATION

    runs = {}
    for kind in ("pd_g", "pd_g_ff"):
        ctl = {"kind": kind, **({"friction_ff": "table_4_1"} if kind == "pd_g_ff" else {})}
        spec = dict(ROTATION, name=kind, controller=ctl, rotation=dict(ROTATION["rotation"], joints=[7]))
        r = run_cli("run", write_yaml(tmp_path / f"{kind}.yaml", spec), "--out", tmp_path / kind, "--quiet")
        assert r.code == 0, r.err
        (runs[kind],) = (tmp_path / kind).iterdir()
    for _ in range(2):
        r = run_cli("friction-id", "--compare", runs["pd_g"], "--compare", runs["pd_g_ff"], "--out", tmp_path / "c",
                    "--quiet")
        assert r.code == 0, r.err
    made = sorted((tmp_path / "c").iterdir())
    assert len(made) == 2 and all(p.name.endswith("-ff-comparison") for p in made)
    for p in made:
        assert sorted(f.name for f in p.glob("ff_comparison.*")) == ["ff_comparison.html", "ff_comparison.json",
                                                                   "ff_comparison.md"]
    assert [ln.split()[-1] for ln in r.out.splitlines() if ln.startswith("wrote ")] == \
        [str(made[-1] / f"ff_comparison.{f}") for f in ("md", "html", "json")]

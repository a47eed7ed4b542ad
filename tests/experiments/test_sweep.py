"""Sweeps on Dask: expansion and validation of the sweep section, points run on a 2-worker LocalCluster,
failures recorded, resume after an interruption (index edited, and a real SIGINT), a worker killed mid-point;
and the MJCF model of the peer benchmark against pinocchio."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from cli_runs import wamctl_completed
from conftest import Q0

from wamctl.errors import SpecError
from wamctl.experiments.sweep.index import open_sweep_dir
from wamctl.experiments.sweep.run import run_sweep
from wamctl.model import params as P
from wamctl.report.sweep import read_index
from wamctl.specs.sweep import VarySection, apply_values, expand_section, load_sweep, sweep_from_mapping

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]
ALL = list(range(1, P.N_JOINTS + 1))


def tiny(vary: dict, hold_s: float = 0.1, **over) -> dict:
    """A rotation of all joints by 0.05 rad (0.4 s of arm time with hold_s = 0.1), Stribeck friction and
    position noise (so that seeds differ), with a vary section."""
    spec = {"kind": "rotation", "name": "tiny", "seed": 0,
            "plant": {"friction": "table_4_1",
                      "effects": {"stribeck": {"joints": ALL, "breakaway_ratio": 1.5}},
                      "sensors": {"position_noise_rad": 1e-4}},
            "q0_rad": Q0.tolist(),
            "rotation": {"mode": "all_together", "amplitude_rad": 0.05, "velocity_rad_s": 0.25, "tc_s": 0.1,
                         "settle_s": 0.0, "hold_s": hold_s},
            "vary": vary}
    spec.update(over)
    return spec


def manifest(run_dir: Path) -> dict:
    return json.loads((Path(run_dir) / "manifest.json").read_text())


def index_rows(sweep_dir: Path) -> dict[str, dict]:
    return {r["point"]: r for r in json.loads((sweep_dir / "index.json").read_text())["points"]}


@pytest.fixture(scope="module")
def client():
    """Two single-threaded worker processes, as `wamctl sweep` starts on this 2-core machine."""
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                       silence_logs=40)
    c = distributed.Client(cluster)
    c.run(lambda: __import__("wamctl.experiments.rotation"))  # warm the workers up (imports, numba caches)
    yield c
    c.close()
    cluster.close()


# ------------------------------------------------------------------------------------ the sweep section
def test_expansion_order_ids_and_value_forms():
    sec = VarySection.model_validate({
        "points": [{"plant.friction": "table_4_1"}, {"plant.friction": "none"}],
        "zip": {"rotation.amplitude_rad": [0.1, 0.2], "rotation.velocity_rad_s": {"linspace": [0.1, 0.3, 2]}},
        "grid": {"seed": {"range": [5, 11, 3]}, "plant.effects.stribeck.breakaway_ratio": [1.2, 2.0]}})
    pts = expand_section(sec)
    assert len(pts) == 2 * 2 * 2 * 2
    assert pts[0] == {"plant.friction": "table_4_1", "rotation.amplitude_rad": 0.1,
                      "rotation.velocity_rad_s": 0.1, "seed": 5, "plant.effects.stribeck.breakaway_ratio": 1.2}
    assert pts[1]["plant.effects.stribeck.breakaway_ratio"] == 2.0 and pts[1]["seed"] == 5  # last key fastest
    assert pts[2]["seed"] == 8 and pts[4]["rotation.velocity_rad_s"] == pytest.approx(0.3)
    assert pts[8]["plant.friction"] == "none"
    sw = sweep_from_mapping(tiny({"grid": {"seed": {"range": [3]}, "q0_rad.3": [1.5, 1.6]}}))
    assert [p.point_id for p in sw.points] == ["p0000", "p0001", "p0002", "p0003", "p0004", "p0005"]
    assert sw.points[3].spec["seed"] == 1 and sw.points[3].spec["q0_rad"][3] == 1.6
    assert sw.points[3].spec["q0_rad"][2] == 0.0 and "vary" not in sw.points[3].spec
    assert sw.parameters == ["seed", "q0_rad.3"] and sw.kind == "rotation" and sw.name == "tiny"


def test_a_friction_sweep_is_varied_through_its_own_sweep_field():
    raw = yaml.safe_load((ROOT / "configs" / "friction_sweep_quick.yaml").read_text())
    raw["vary"] = {"grid": {"sweep.joints": [[1], [7]], "seed": [0, 1]}}
    sw = sweep_from_mapping(raw, "fs.yaml")
    assert sw.kind == "friction_sweep" and len(sw.points) == 4
    assert [p.spec["sweep"]["joints"] for p in sw.points] == [[1], [1], [7], [7]]
    assert sw.points[3].spec["sweep"]["travel_rad"] == {1: 0.8, 7: 1.5}  # the rest of its schedule is kept


def test_hmi_subjects_crossed_with_conditions():
    raw = yaml.safe_load((ROOT / "configs" / "hmi_block.yaml").read_text())
    raw["vary"] = {"points": [{"hmi.subject": {"id": "S1", "seed": 11, "skill": 0.8}},
                              {"hmi.subject": {"id": "S2", "seed": 12, "skill": 0.6}}],
                   "grid": {"hmi.strategy": ["four", "vector"], "hmi.filter.window_s": [0.3, 0.5]}}
    sw = sweep_from_mapping(raw, "hmi.yaml")
    assert sw.kind == "hmi_block" and len(sw.points) == 8
    p5 = sw.points[5].spec["hmi"]
    assert p5["subject"]["id"] == "S2" and p5["strategy"] == "four" and p5["filter"] == {"kind": "ma", "window_s": 0.5}
    assert p5["profile"] == raw["hmi"]["profile"]


def test_paths_into_missing_mappings_and_joint_keyed_mappings():
    base = {"plant": {"friction": {"joints": {1: {"fc_pos_Nm": 1.0}}}}}
    out = apply_values(base, {"plant.friction.joints.1.fc_pos_Nm": 2.5, "plant.effects.payload.mass_kg": 1.0})
    assert out["plant"]["friction"]["joints"][1]["fc_pos_Nm"] == 2.5 and "1" not in out["plant"]["friction"]["joints"]
    assert out["plant"]["effects"] == {"payload": {"mass_kg": 1.0}}
    assert base["plant"]["friction"]["joints"][1]["fc_pos_Nm"] == 1.0  # the base is not modified


@pytest.mark.parametrize("vary, message", [
    ({"grid": {"plant.effects.stribeck.breakaway_ratio": [1.5, 0.5]}},
     "point p0001 (plant.effects.stribeck.breakaway_ratio=0.5): plant.effects.stribeck.breakaway_ratio: "
     "Input should be greater than 1"),
    ({"grid": {"rotation.amplitud_rad": [0.1]}}, "point p0000 (rotation.amplitud_rad=0.1): rotation.amplitud_rad: "
                                                 "unknown key"),
    ({"grid": {"q0_rad.9": [0.1]}}, "q0_rad.9: index 9 outside the list of 7"),
    ({"grid": {"seed": {"range": [0, 10, 0]}}}, "vary.grid.seed: range step must not be 0"),
    ({"grid": {"seed": {"from": 1}}}, "vary.grid.seed: give a list of values"),
    ({"zip": {"seed": [1, 2], "rotation.hold_s": [1.0]}}, "vary.zip: the lists must have equal lengths"),
    ({"grid": {"kind": ["ift"]}}, "`kind` cannot be swept"),
    ({"grid": {"seed": [1]}, "points": [{"seed": 2}]}, "seed is varied in both points and grid"),
    ({"gird": {"seed": [1]}}, "s.yaml: vary.gird: unknown key"),
    ({}, "s.yaml: vary: needs at least one of grid, zip or points"),
])
def test_bad_sweeps_name_the_point_and_field(vary, message):
    with pytest.raises(SpecError) as exc:
        sweep_from_mapping(tiny(vary), "s.yaml")
    assert message in str(exc.value)


def test_every_invalid_point_is_reported_before_anything_runs():
    with pytest.raises(SpecError) as exc:
        sweep_from_mapping(tiny({"grid": {"rotation.velocity_rad_s": [0.1, -1.0, 3.0]}}), "s.yaml")
    msg = str(exc.value)
    assert msg.startswith("2 of 3 sweep points are invalid (nothing was run)")
    assert "point p0001 (rotation.velocity_rad_s=-1.0)" in msg and "point p0002 (rotation.velocity_rad_s=3.0)" in msg


def test_a_mistake_every_point_inherits_is_said_once():
    """An unknown key in the spec itself breaks all 12 points alike: one line, not 12 (a user saw the same key
    on 20 lines and '... and 80 more'); points that share a problem are named together."""
    spec = tiny({"grid": {"seed": {"range": [12]}}})
    spec["rotation"]["amplitud_rad"] = 0.2
    with pytest.raises(SpecError) as exc:
        sweep_from_mapping(spec, "s.yaml")
    assert str(exc.value) == ("12 of 12 sweep points are invalid (nothing was run):\n"
                              "s.yaml: all 12 points: rotation.amplitud_rad: unknown key")
    with pytest.raises(SpecError) as exc:
        sweep_from_mapping(tiny({"grid": {"rotation.velocity_rad_s": [0.1, -1.0, -2.0, 3.0]}}), "s.yaml")
    lines = str(exc.value).splitlines()
    assert lines[0] == "3 of 4 sweep points are invalid (nothing was run):" and len(lines) == 3
    assert lines[1].startswith("s.yaml: points p0001 (rotation.velocity_rad_s=-1.0), p0002 (rotation.velocity_rad_s"
                               "=-2.0): rotation.velocity_rad_s:")
    assert lines[2].startswith("s.yaml: point p0003 (rotation.velocity_rad_s=3.0): rotation.velocity_rad_s:")


# ------------------------------------------------------------------------------------ running on Dask
def test_sweep_runs_every_point_into_ordinary_run_dirs(tmp_path, client):
    sw = sweep_from_mapping(tiny({"grid": {"plant.effects.stribeck.breakaway_ratio": [1.2, 3.0],
                                           "seed": {"range": [2]}}}), "s.yaml")
    res = run_sweep(sw, tmp_path, client=client)
    assert res.ok and res.ran == 4 and res.skipped == 0 and res.counts["completed"] == 4
    assert res.n_workers == 2 and res.max_concurrent == 2           # both workers ran points at the same time
    idx = read_index(res.sweep_dir)
    assert list(idx["point"]) == [f"p000{i}" for i in range(4)]
    assert list(idx["seed"]) == [0, 1, 0, 1]
    assert list(idx["plant.effects.stribeck.breakaway_ratio"]) == [1.2] * 2 + [3.0] * 2
    assert set(idx["status"]) == {"completed"} and set(idx["attempts"]) == {1}
    assert idx["worker"].nunique() == 2
    for _, row in idx.iterrows():
        run = res.sweep_dir / row["run_dir"]
        assert run.parent.name == row["point"]                       # runs/<point>/<stamp>-tiny
        m = manifest(run)
        assert m["status"] == "completed" and m["seed"] == row["seed"]
        assert m["sweep"]["point"] == row["point"] and m["sweep"]["values"]["seed"] == row["seed"]
        spec = yaml.safe_load((run / "spec.yaml").read_text())     # the resolved spec has the swept value
        assert spec["plant"]["effects"]["stribeck"]["breakaway_ratio"] == \
            row["plant.effects.stribeck.breakaway_ratio"]
        rpe = json.loads((run / "report.json").read_text())["rpe_pct"]
        assert row["rpe_pct.1"] == pytest.approx(rpe["1"]) and row["rpe_pct.7"] == pytest.approx(rpe["7"])
    # seeds draw different sensor noise; a stronger breakaway leaves larger errors at the end of the move
    assert idx.loc[0, "rpe_pct.7"] != idx.loc[1, "rpe_pct.7"]
    rpe_cols = [f"rpe_pct.{j}" for j in ALL]
    by = idx.groupby("plant.effects.stribeck.breakaway_ratio")[rpe_cols].mean().mean(axis=1)
    assert by[3.0] > by[1.2]
    m = json.loads((res.sweep_dir / "sweep.json").read_text())
    assert m["format"] == "wamctl-sweep/1" and m["status"] == "completed" and m["n_points"] == 4
    assert m["counts"]["completed"] == 4 and m["sessions"][0]["n_workers"] == 2
    rep = json.loads((res.sweep_dir / "report.json").read_text())
    assert len(rep["tables"]["points"]) == 4 and len(rep["tables"]["key_figures"]) == 4
    assert set(rep["by_parameter"]["plant.effects.stribeck.breakaway_ratio"]) == {"1.2", "3.0"}
    # beside each mean its spread over the points (two seeds per value here), and every point in a figure
    sd = rep["sd_by_parameter"]["plant.effects.stribeck.breakaway_ratio"]
    want = idx.groupby("plant.effects.stribeck.breakaway_ratio")["rpe_pct.7"].std(ddof=1)
    assert sd["3.0"]["rpe_pct.7"] == pytest.approx(want[3.0]) and sd["1.2"]["n_points"] == 2
    assert (res.sweep_dir / "by_plant_effects_stribeck_breakaway_ratio.png").stat().st_size > 0
    assert (res.sweep_dir / "report.html").stat().st_size > 0 and (res.sweep_dir / "index.csv").is_file()


def test_failed_points_are_recorded_and_the_others_complete(tmp_path, client):
    spec = tiny({"points": [{"plant.friction": "table_4_1"}, {"plant.friction": "no_such_model.yaml"},
                            {"controller.kd": [-30.0, 20.0, 5.0, 2.0, 0.5, 0.5, 0.05]}],
                 "grid": {"seed": [0, 1]}, "reports": False})
    seen = []
    res = run_sweep(sweep_from_mapping(spec, "s.yaml"), tmp_path, client=client, on_point=seen.append)
    assert not res.ok and res.counts == {"completed": 2, "failed": 4, "interrupted": 0, "pending": 0}
    assert sorted(r["point"] for r in seen) == [f"p000{i}" for i in range(6)]
    rows = index_rows(res.sweep_dir)
    assert [rows[p]["status"] for p in sorted(rows)] == ["completed"] * 2 + ["failed"] * 4
    for p in ("p0002", "p0003"):   # the friction model file does not exist: refused by the run, not retried
        assert "friction model file not found: no_such_model.yaml" in rows[p]["error"]
        assert rows[p]["attempts"] == 1
    for p in ("p0004", "p0005"):   # negative damping: the run starts, trips the velocity limit, ends failed
        assert rows[p]["error"].startswith("safety limit: joint 1 velocity")
        assert manifest(res.sweep_dir / rows[p]["run_dir"])["status"] == "failed"
    idx = read_index(res.sweep_dir)
    assert idx.loc[idx["status"] == "failed", "error"].notna().all()


def test_resume_runs_only_the_missing_points(tmp_path, client):
    sw = sweep_from_mapping(tiny({"grid": {"seed": {"range": [6]}}, "reports": False}), "s.yaml")
    res = run_sweep(sw, tmp_path, client=client)
    before = index_rows(res.sweep_dir)
    # an interruption, simulated: p0001 never ran, p0003 was running (its run directory is gone), p0004's
    # run directory was deleted after it completed
    doc = json.loads((res.sweep_dir / "index.json").read_text())
    for r in doc["points"]:
        if r["point"] in ("p0001", "p0003"):
            r.update(status={"p0001": "pending", "p0003": "interrupted"}[r["point"]], run_dir=None)
    (res.sweep_dir / "index.json").write_text(json.dumps(doc))
    for p in ("p0001", "p0003", "p0004"):
        for d in (res.sweep_dir / "runs" / p).iterdir():
            for f in sorted(d.rglob("*"), reverse=True):
                f.rmdir() if f.is_dir() else f.unlink()
            d.rmdir()
    sw2, _ = open_sweep_dir(res.sweep_dir)
    res2 = run_sweep(sw2, resume_dir=res.sweep_dir, client=client)
    assert res2.ok and res2.ran == 3 and res2.skipped == 3
    after = index_rows(res.sweep_dir)
    for p in ("p0000", "p0002", "p0005"):
        assert after[p]["run_dir"] == before[p]["run_dir"] and after[p]["end_unix_s"] == before[p]["end_unix_s"]
    for p in ("p0001", "p0003", "p0004"):
        assert after[p]["run_dir"] != before[p]["run_dir"] and after[p]["status"] == "completed"
        assert manifest(res.sweep_dir / after[p]["run_dir"])["status"] == "completed"
    m = json.loads((res.sweep_dir / "sweep.json").read_text())
    assert [s["ran"] for s in m["sessions"]] == [6, 3] and m["status"] == "completed"
    # nothing left: a third call runs nothing (and needs no cluster)
    res3 = run_sweep(sw2, resume_dir=res.sweep_dir)
    assert res3.ran == 0 and res3.skipped == 6


def test_a_worker_killed_mid_point_retries_the_point(tmp_path, client):
    sw = sweep_from_mapping(tiny({"grid": {"seed": {"range": [6]}}, "reports": False}, hold_s=6.0), "s.yaml")
    pids = set(client.run(os.getpid).values())
    box = {}
    th = threading.Thread(target=lambda: box.update(res=run_sweep(sw, tmp_path, client=client)))
    th.start()
    killed = None
    deadline = time.time() + 120
    while killed is None and time.time() < deadline and th.is_alive():
        for d in tmp_path.glob("*-sweep/runs/*/*"):
            try:
                m = manifest(d)
            except (OSError, json.JSONDecodeError):
                continue
            if m.get("status") == "running" and m.get("pid") in pids:
                os.kill(m["pid"], signal.SIGKILL)
                killed = (d.parent.name, d, m["pid"])
                break
        time.sleep(0.005)
    th.join(timeout=300)
    assert killed is not None, "no point was seen running"
    res = box["res"]
    rows = index_rows(res.sweep_dir)
    assert len(rows) == 6 and all(r["status"] in ("completed", "failed") for r in rows.values())  # none lost
    point, first_attempt, pid = killed
    assert rows[point]["status"] == "completed" and rows[point]["attempts"] == 2
    assert rows[point]["run_dir"] != str(first_attempt.relative_to(res.sweep_dir))
    m = manifest(first_attempt)
    # recorded as `wamctl runs --mark-abandoned` does, its samples kept
    assert (m["status"], m["reason"]) == ("interrupted", "process ended without closing the run")
    assert m["abandoned"]["known_by"].startswith("sweep: the point given to another worker")
    assert res.counts["completed"] == 6
    assert pid not in set(client.run(os.getpid).values())  # the nanny replaced the killed worker


@pytest.mark.parametrize("presses", [1, 2], ids=["ctrl-c", "ctrl-c-twice"])
def test_ctrl_c_writes_the_index_and_resume_finishes_the_missing_points(tmp_path, client, presses):
    """Ctrl-C once, or twice (a user who does not see the sweep stop at once: the second press comes while the
    index is written and the cluster closes, and must not break either)."""
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(tiny({"grid": {"seed": {"range": [12]}}, "reports": False}, hold_s=1.5)))
    out = tmp_path / "out"
    # SIGINT to the whole process group, as a terminal's Ctrl-C does (the handler restored in case this test
    # runs from a shell that ignores SIGINT in background jobs)
    code = ("import signal, sys\nif __name__ == '__main__':\n"
            "    signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "    sys.argv = ['wamctl'] + sys.argv[1:]\n    from wamctl.cli import main\n    main()\n")
    launcher = tmp_path / "launch.py"
    launcher.write_text(code)
    proc = subprocess.Popen([sys.executable, str(launcher), "sweep", str(spec), "--out", str(out), "--workers", "2",
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=ROOT)
    try:
        deadline = time.time() + 180
        done = 0
        while time.time() < deadline and proc.poll() is None:
            idx = list(out.glob("*-sweep/index.json"))
            if idx:
                try:
                    done = json.loads(idx[0].read_text())["counts"]["completed"]
                except (OSError, json.JSONDecodeError, KeyError):
                    done = 0
                if done >= 2:
                    break
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        os.killpg(proc.pid, signal.SIGINT)
        if presses == 2:
            time.sleep(0.3)
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "sweep interrupted" in err and "--resume" in err and "Traceback" not in err
    sweep_dir = next(out.glob("*-sweep"))
    rows = index_rows(sweep_dir)
    counts = json.loads((sweep_dir / "index.json").read_text())["counts"]
    assert len(rows) == 12 and sum(counts.values()) == 12
    assert 2 <= counts["completed"] < 12 and counts["failed"] == 0
    assert json.loads((sweep_dir / "sweep.json").read_text())["status"] == "interrupted"
    completed_before = {p: r["run_dir"] for p, r in rows.items() if r["status"] == "completed"}

    sw, _ = open_sweep_dir(sweep_dir)
    assert [p.spec for p in sw.points] == [p.spec for p in load_sweep(spec).points]
    res = run_sweep(sw, resume_dir=sweep_dir, client=client)
    assert res.ok and res.counts["completed"] == 12
    # only the missing points ran (a point that finished on a worker after Ctrl-C is adopted, not re-run)
    assert res.ran + res.skipped == 12 and res.ran <= 12 - len(completed_before)
    after = index_rows(sweep_dir)
    assert all(after[p]["run_dir"] == d for p, d in completed_before.items())
    # a point's times are the worker's (they contain its run's own span); a point adopted because it finished
    # after Ctrl-C has none to show, rather than its run's span as if it were the point's duration
    import datetime as dt
    for r in after.values():
        m = manifest(sweep_dir / r["run_dir"])
        if r["start_unix_s"] is None:
            assert r["end_unix_s"] is None
            continue
        span = [dt.datetime.fromisoformat(m[k]).timestamp() for k in ("start_utc", "end_utc")]
        assert r["start_unix_s"] <= span[0] + 1e-3 and r["end_unix_s"] >= span[1] - 1e-3
    runs = [d for d in (sweep_dir / "runs").glob("*/*") if manifest(d)["status"] == "completed"]
    assert len(runs) == 12  # one completed run per point: nothing ran twice


def test_cli_resume_refuses_another_spec(tmp_path, client):
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(tiny({"grid": {"seed": [0, 1]}, "reports": False})))
    res = run_sweep(load_sweep(spec), tmp_path / "out", client=client)
    other = tmp_path / "o.yaml"
    other.write_text(yaml.safe_dump(tiny({"grid": {"seed": [0, 2]}, "reports": False})))
    r = wamctl_completed("sweep", other, "--resume", res.sweep_dir)
    assert r.returncode == 2 and "not the spec of the sweep" in r.stderr
    r = wamctl_completed("sweep", spec, "--dry-run", "--json")
    assert r.returncode == 0, r.stderr
    assert [p["seed"] for p in json.loads(r.stdout)["points"]] == [0, 1]


def test_example_sweep_config_has_100_valid_points():
    sw = load_sweep(ROOT / "configs" / "sweep_friction_seeds.yaml")
    assert len(sw.points) == 100 and len({json.dumps(p.values) for p in sw.points}) == 100


# ------------------------------------------------------------------------------------ the peer model

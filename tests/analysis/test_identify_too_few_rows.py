"""identify on a log whose joints never slide (a regulation: steps held, as the cvrg-wam4 recording of
docs/real-data.md) says where the samples went, in one line, exit 2; it used to ask "did any joint move?" of a
log whose joints all moved."""

from __future__ import annotations

import numpy as np
import pandas as pd
import yaml
from cli_runs import run_cli

from wamctl.model.dynamics import WamDynamics
from wamctl.model.robots import get_robot

RATE_HZ = 500.0


def regulation_run(out):
    """Each wam4 joint steps 0.1 rad in 0.05 s (a smoothstep), then is held for 2 s; the datasheet arm's torque."""
    t = np.arange(0.0, 2.5, 1.0 / RATE_HZ)
    s = np.clip((t - 0.2) / 0.05, 0.0, 1.0)
    step, dstep, ddstep = s * s * (3 - 2 * s), 6 * s * (1 - s) / 0.05, (6 - 12 * s) / 0.05 ** 2 * ((s > 0) & (s < 1))
    q0 = np.array([0.0, -1.2, 0.0, 1.5])
    q = q0 + 0.1 * step[:, None] * np.ones(4)
    qd, qdd = 0.1 * dstep[:, None] * np.ones(4), 0.1 * ddstep[:, None] * np.ones(4)
    tau = WamDynamics(robot="wam4").inverse_dynamics_many(q, qd, qdd)
    df = pd.DataFrame({"t": t})
    for j in range(4):
        df[f"q_ref_{j + 1}"], df[f"q_{j + 1}"], df[f"tau_{j + 1}"] = q[:, j], q[:, j], tau[:, j]
    out.mkdir()
    df.to_parquet(out / "data.parquet", index=False)
    wam4 = get_robot("wam4")
    (out / "meta.yaml").write_text(yaml.safe_dump({
        "format": "wamctl-measured/1", "robot": "wam4", "sample_rate_hz": RATE_HZ, "gravity_compensation": True,
        "controller": {"kind": "pd_g", "kp": wam4.kp.tolist(), "kd": wam4.kd.tolist()},
        "experiment": {"kind": "free", "joints": [1, 2, 3, 4]}, "q0": q0.tolist()}, sort_keys=False))
    return out


def test_a_regulation_log_is_refused_with_where_its_samples_went(tmp_path):
    r = run_cli("identify", regulation_run(tmp_path / "reg"), "--out", tmp_path / "an")
    assert r.code == 2 and r.exc is None, r.out + r.err + r.tb
    lines = [ln for ln in r.err.strip().splitlines() if ln.startswith("error")]
    assert len(lines) == 1, r.err
    # each joint moved 0.1 rad, sliding for some 50 ms: named with its travel and sliding samples
    for j in (1, 2, 3, 4):
        assert f"joint {j}: moved 0.1000 rad with" in lines[0], lines[0]
    assert "did any joint move" not in lines[0]

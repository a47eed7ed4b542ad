"""The strategy comparison of thesis section 5.4: the task on the plant under PD + gravity, PD + gravity +
feed-forward friction (eq. 4.3 with the identified friction) and the tuned PID; ``compare-{strategy}.parquet``."""

from __future__ import annotations

import numpy as np
import pandas as pd

from wamctl.experiments.ift.experiments import IftExperiments
from wamctl.experiments.ift.planning import comparison_feedforward_Nm, task_reference
from wamctl.experiments.ift.state import write_parquet
from wamctl.model.plant import resolve_friction
from wamctl.report.ift import comparison_file

STRATEGIES = ("pd_g", "pd_g_ff", "pid")


def compare_strategies(lab: IftExperiments, tuned: np.ndarray) -> None:
    """Every tuned joint's task once per strategy on the plant; ``tuned`` (7, 3) are the PID's gains. The PD
    strategies use the initial kp, kd (ki = 0)."""
    friction = resolve_friction(lab.s.identified_friction, lab.base_dir)
    pd_gains = lab.g0.copy()
    pd_gains[:, 2] = 0.0
    for strategy in STRATEGIES:
        parts = []
        for n, joint in enumerate(lab.s.joints):
            if lab.progress:
                lab.progress(n, len(lab.s.joints), f"comparison {strategy}: joint {joint}")
            ref, n_task = task_reference(lab.spec, joint, lab.with_return)
            ff = comparison_feedforward_Nm(lab.spec, ref, friction) if strategy == "pd_g_ff" else None
            gains = tuned if strategy == "pid" else pd_gains
            seed = lab._plant_seed(10_000, joint, STRATEGIES.index(strategy))
            rows, cols, reason = lab._run_backend(joint, gains, ref, seed, ff)
            df = pd.DataFrame(rows[:n_task], columns=cols)
            df.insert(0, "joint", joint)
            parts.append(df)
            if reason is not None:
                lab.run.event(lab.plant_time_s, "comparison_failed", joint, f"{strategy}: {reason}")
        write_parquet(lab.run.path / comparison_file(strategy), pd.concat(parts, ignore_index=True))
        lab.run.event(lab.plant_time_s, "comparison", None, f"{strategy} done")

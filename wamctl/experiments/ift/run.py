"""The runner's entry points: a new tuning (:func:`execute`) and an interrupted one continued from its run
directory (:func:`resume`, ``wamctl tune-ift --resume``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from wamctl.errors import SpecError
from wamctl.experiments.common import Plan
from wamctl.experiments.ift.planning import plan
from wamctl.experiments.ift.tuner import IftTuner
from wamctl.runs.store import RunDir, open_run, read_events, utc_now
from wamctl.specs.ift import IftSpec


def execute(spec: IftSpec, plan: Plan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    """The runner's entry point: a new tuning of ``spec`` into ``run``."""
    tuner = IftTuner(spec, run, base_dir, progress)
    run.update_manifest(backend={"name": spec.backend.kind if spec.ift.plant.source == "backend" else "measured"},
                        ift={"phase": "tuning"})
    tuner.execute()


def resume(run_path: str | Path, spec: IftSpec, base_dir: Path | None = None, progress=None):
    """Continue an interrupted tuning in ``run_path`` from its last completed iteration.

    ``spec`` must equal the run's ``spec.yaml`` except for ``ift.plant.runs`` (more measured runs may be given).
    Returns a :class:`wamctl.experiments.runner.RunOutcome`; raises RunInterrupted if interrupted again.
    """
    from wamctl.experiments.runner import record_outcome
    run_path = Path(run_path)
    manifest, stored = open_run(run_path)
    if manifest.get("kind") != "ift":
        raise SpecError(f"{run_path}: --resume needs an ift run directory, not a {manifest.get('kind')!r} run")
    new = spec.model_dump(mode="json")
    diff = spec_differences(stored, new)
    if diff:
        raise SpecError(f"{run_path}: the spec differs from the run's spec.yaml in {', '.join(diff)}; resume with "
                        f"the same spec (only ift.plant.runs may grow)")
    if new["ift"]["plant"]["runs"] != stored["ift"]["plant"]["runs"]:
        (run_path / "spec.yaml").write_text(yaml.safe_dump(new, sort_keys=False))
    p = plan(spec, base_dir)
    p.check_limits()
    run = RunDir(run_path)
    ev = read_events(run_path)
    run._events = [{"t_s": float(r.t_s), "kind": r.kind, "joint": None if pd.isna(r.joint) else int(r.joint),
                    "detail": "" if pd.isna(r.detail) else str(r.detail)} for r in ev.itertuples()]
    tuner = IftTuner(spec, run, base_dir, progress)
    tuner.load_state()
    run.event(tuner.plant_time_s, "ift_resumed", None,
              f"resumed after iteration {tuner.iteration} (phase {tuner.phase}), previous status "
              f"{manifest.get('status')}")
    run.update_manifest(status="running", reason=None, end_utc=None,
                        resumed=list(manifest.get("resumed") or []) + [utc_now()])
    return record_outcome(run, lambda: tuner.execute(), resume_hint=True)


def spec_differences(old, new, prefix="") -> list[str]:
    """Dotted paths where two spec dumps differ (numbers compared at 12 digits), ignoring what a resume may
    change: ``ift.plant.runs`` and ``out_dir``."""
    out = []
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            path = f"{prefix}.{k}" if prefix else str(k)
            if path in ("ift.plant.runs", "out_dir"):
                continue
            out += spec_differences(old.get(k), new.get(k), path)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new)):
            out += spec_differences(a, b, f"{prefix}[{i}]")
        return out
    if isinstance(old, (int, float)) and isinstance(new, (int, float)) and not isinstance(old, bool):
        return [] if np.isclose(float(old), float(new), rtol=1e-12, atol=0) else [prefix]
    return [] if old == new else [prefix]

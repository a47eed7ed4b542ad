"""The runner's entry points: a new block (:func:`execute`) and an interrupted one continued at its next trial
(:func:`resume`, ``wamctl hmi-session --resume``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from wamctl.errors import SpecError
from wamctl.experiments.hmi_block.block import HmiBlock
from wamctl.experiments.hmi_block.planning import HmiPlan, plan
from wamctl.runs.store import RunDir, open_run, read_events, utc_now
from wamctl.specs.hmi_block import HmiBlockSpec


def execute(spec: HmiBlockSpec, plan: HmiPlan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    HmiBlock(spec, plan, run, progress, base_dir).execute()


def resume(run_path: str | Path, spec: HmiBlockSpec | None = None, progress=None):
    """Continue an interrupted block in ``run_path`` at its next trial.

    ``spec``, if given, must have the same ``hmi`` section as the run's ``spec.yaml``. Returns a
    :class:`wamctl.experiments.runner.RunOutcome`; raises ``RunInterrupted`` if interrupted again.
    """
    from wamctl.experiments.runner import record_outcome
    from wamctl.specs import parse_spec

    run_path = Path(run_path)
    manifest, stored = open_run(run_path)
    if manifest.get("kind") != "hmi_block":
        raise SpecError(f"{run_path}: --resume needs an hmi_block run directory, not a {manifest.get('kind')!r} run")
    run_spec = parse_spec(stored, str(run_path / "spec.yaml"))
    if spec is not None and spec.hmi.model_dump(mode="json") != run_spec.hmi.model_dump(mode="json"):
        raise SpecError(f"{run_path}: the spec's hmi section differs from the run's spec.yaml; resume with the same "
                        f"spec (or without one)")
    base = (manifest.get("hmi") or {}).get("base_dir")
    base_dir = Path(base) if base else None
    p = plan(run_spec, base_dir)
    p.check_limits()
    run = RunDir(run_path)
    for r in read_events(run_path).itertuples():
        run.event(float(r.t_s), str(r.kind), None if pd.isna(r.joint) else int(r.joint),
                  "" if pd.isna(r.detail) else str(r.detail))
    run.event(0.0, "resumed", None, f"previous status {manifest.get('status')}")
    run.update_manifest(status="running", reason=None, end_utc=None,
                        resumed=list(manifest.get("resumed") or []) + [utc_now()])
    return record_outcome(run, lambda: execute(run_spec, p, run, progress, base_dir), resume_hint=True)

"""The one registry of run kinds: kind -> spec model, experiment (plan / execute), report.

Entries name their targets as ``"module:attribute"`` strings resolved at first use (python-can's interface
registry does the same), so reading the registry imports nothing and a lower layer never imports an upper one:
:mod:`wamctl.specs` resolves ``spec``, :mod:`wamctl.experiments.runner` resolves ``experiment``,
:mod:`wamctl.report` resolves ``report``.

Adding an experiment kind is one entry here plus its own modules: a spec model (a subclass of
:class:`wamctl.specs.common.Common` with ``kind: Literal["..."]``) in ``wamctl/specs/``, a module with
``plan(spec, base_dir) -> Plan`` and ``execute(spec, plan, run, progress, base_dir)`` (and optionally
``resume``) in ``wamctl/experiments/``, and ``report(run_path, manifest, spec, out_dir) -> Document`` in
``wamctl/report/``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Kind:
    """One run kind. ``spec`` and ``experiment`` are None for runs not made from a spec (analyses, imports)."""

    name: str
    report: str
    spec: str | None = None
    experiment: str | None = None


KINDS: dict[str, Kind] = {k.name: k for k in (
    Kind("rotation", spec="wamctl.specs.rotation:RotationSpec", experiment="wamctl.experiments.rotation",
         report="wamctl.report.rotation:report"),
    Kind("friction_sweep", spec="wamctl.specs.friction_sweep:FrictionSweepSpec",
         experiment="wamctl.experiments.friction_sweep", report="wamctl.report.friction:report"),
    Kind("ift", spec="wamctl.specs.ift:IftSpec", experiment="wamctl.experiments.ift",
         report="wamctl.report.ift:report"),
    Kind("hmi_block", spec="wamctl.specs.hmi_block:HmiBlockSpec", experiment="wamctl.experiments.hmi_block",
         report="wamctl.report.hmi:report"),
    Kind("excitation", spec="wamctl.specs.excitation:ExcitationSpec", experiment="wamctl.experiments.excitation",
         report="wamctl.report.excitation:report"),
    Kind("diagnosis", report="wamctl.report.diagnosis:report"),
    Kind("identification", report="wamctl.report.identification:report"),
    Kind("measured", report="wamctl.report.measured:report"),
)}

SPEC_KINDS: tuple[str, ...] = tuple(k for k, v in KINDS.items() if v.spec)


def resolve(target: str) -> Any:
    """The object a ``"module:attribute"`` (or ``"module"``) target names."""
    module, _, attr = target.partition(":")
    mod = importlib.import_module(module)
    return getattr(mod, attr) if attr else mod

"""Backends: the arm behind one small protocol (:class:`~wamctl.backends.base.ArmBackend`), simulated or real.

What lives here: the shared safety base (:mod:`.base`: limits, watchdog, zero torque on exit), the simulated
WAM (:mod:`.sim`), the real arm over CAN (:mod:`.can`: the backend, the puck protocol, simulated pucks, bus
tools), the gaze tracker's sources (:mod:`.gaze`: serial, replay, the virtual subject), and the registry below:
``backend.kind`` of a spec -> ``"module:Class"``, imported only when used.

May import: specs (typed backend specs), control, hmi, model, runs, io, errors. Never analysis, experiments,
report or the CLI.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# backend.kind -> "module:Class"; each class has ``from_spec(spec, base_dir, q0_rad, rng)``
BACKENDS: dict[str, str] = {
    "sim": "wamctl.backends.sim:SimBackend",
    "can": "wamctl.backends.can.backend:CanBackend",
}


def make_backend(spec, base_dir: Path | None = None, q0_rad=None, seed: int | None = None):
    """The backend ``spec.backend`` names, at rest at ``q0_rad`` (default ``spec.q0_rad``); random draws seeded
    with ``seed`` (default ``spec.seed``)."""
    import importlib

    from wamctl.errors import SpecError

    target = BACKENDS.get(spec.backend.kind)
    if target is None:
        raise SpecError(f"backend.kind: unknown backend {spec.backend.kind!r}; known: {', '.join(BACKENDS)}")
    module, _, cls = target.partition(":")
    backend_cls = getattr(importlib.import_module(module), cls)
    q0 = np.asarray(spec.q0_rad if q0_rad is None else q0_rad, float)
    return backend_cls.from_spec(spec, base_dir, q0, np.random.default_rng(spec.seed if seed is None else seed))

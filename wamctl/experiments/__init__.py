"""Experiments: running a spec, and the recorded-data pipelines.

What lives here: the runner (:mod:`.runner`: plan -> run directory -> execute -> status -> report), the
closed-loop engine (:mod:`.engine`), the stages every kind shares (:mod:`.common`), one module or package per
kind (``rotation``, ``friction_sweep``, ``ift``, ``hmi_block``, named in :data:`wamctl.specs.registry.KINDS`),
sweeps of many runs (:mod:`.sweep`), and the pipelines over recorded data (:mod:`.diagnose`; the friction
identification of a recorded sweep in :mod:`.friction_sweep`).

May import: report, analysis, backends, specs, runs, hmi, control, model, io, errors. Never the CLI.
"""

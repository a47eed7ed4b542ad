"""Sweeps: one spec, many runs. The ``vary:`` section of a spec (:mod:`wamctl.specs.sweep`) names the fields to
vary; each point becomes an ordinary run directory, executed on a Dask cluster, and one sweep directory
indexes them; its combined report is :mod:`wamctl.report.sweep`.

What lives here: running the sweep (:mod:`.run`: ``run_sweep``, resume, the plan check of every point), one
point on a worker (:mod:`.point`), the sweep directory and its index (:mod:`.index`), and the Dask cluster
(:mod:`.cluster`).

May import: report, analysis, backends, specs, runs, hmi, control, model, io, errors (and dask.distributed,
imported only when a sweep runs). Never the CLI.

The sweep directory
-------------------
``<out>/<UTC time>-<name>-sweep/``::

    sweep.yaml        the spec as given, with its vary section
    sweep.json        manifest: format wamctl-sweep/1, source, base_dir, points, status, cluster, timing
    index.json/.csv   one row per point: point, parameter values, status, attempts, run_dir, error,
                      worker, start/end, and the run's key figures (numbers of its report's data)
    runs/<point>/     the point's run directories (one per attempt; a lost attempt is marked failed)
    report.md/.html/.json   the combined report: index, key figures, key figures per parameter value

Point status: ``completed`` (its run completed), ``failed`` (the run failed, its spec or plan was refused,
or it kept erroring; ``error`` says why), ``interrupted`` (running when the sweep was stopped),
``pending`` (not started). ``resume`` runs every point that is not ``completed``.

Execution is on Dask only (:mod:`dask.distributed`): a ``LocalCluster`` of one single-threaded process per
core by default, or any running scheduler by address (the sweep directory must then be on a file system the
workers share, at the same path). Results are collected as they finish; a worker lost mid-point
makes the scheduler run the point again elsewhere (up to ``distributed.scheduler.allowed-failures``, then it
is recorded failed with ``KilledWorker``); an exception is retried ``retries`` times by Dask.
"""

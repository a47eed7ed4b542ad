"""The Dask cluster of a sweep: a local cluster of single-threaded worker processes, or a running scheduler by
address. :mod:`distributed` is imported only here, and only when a sweep runs."""

from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from pathlib import Path

from wamctl.errors import BackendError, SpecError

log = logging.getLogger(__name__)


def default_n_workers() -> int:
    """Cores this process may use (CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def import_distributed():
    """The :mod:`distributed` package, or a :class:`BackendError` saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise BackendError("wamctl sweep needs dask.distributed: pip install 'dask[distributed]'") from None
    return distributed


def dask_versions() -> dict:
    """Installed versions of dask and distributed (None when missing), for the sweep manifest."""
    from importlib import metadata
    out = {}
    for n in ("dask", "distributed"):
        try:
            out[n] = metadata.version(n)
        except metadata.PackageNotFoundError:
            out[n] = None
    return out


LOOPBACK = "127.0.0.1"
"""Where a local cluster's scheduler, workers and dashboard listen."""


def start_local_cluster(n_workers: int | None = None):
    """A ``LocalCluster`` of ``n_workers`` single-threaded worker processes (default: one per core) and
    its client. Returns ``(cluster, client)``.

    The workers ignore SIGINT (a plugin, so restarted workers do too): Ctrl-C in a terminal reaches the
    whole process group, and only the client should act on it (write the index, then close the cluster).
    """
    distributed = import_distributed()
    n = n_workers or default_n_workers()
    # The cluster's own log lines stay out of the terminal (CRITICAL only): a point's failure reaches the user
    # through its future (the exception, or KilledWorker after the allowed deaths) and is written to the index;
    # what the workers log at ERROR is the cluster's plumbing, e.g. a heartbeat that finds the scheduler gone
    # while the cluster closes after Ctrl-C on a loaded machine, printed with a traceback after "sweep interrupted".
    with _sigint_blocked():
        # nothing it opens is reachable from the lab network: scheduler, workers and dashboard on the loopback
        # interface only (the dashboard's ":0" listened on every interface; issue 30)
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host=LOOPBACK,
                                           dashboard_address=f"{LOOPBACK}:0", silence_logs=logging.CRITICAL)
    client = distributed.Client(cluster)
    client.register_plugin(_ignore_sigint_plugin(), name="wamctl-ignore-sigint")
    return cluster, client


@contextmanager
def _sigint_blocked():
    """SIGINT blocked in this thread while the cluster starts (issue 32): the processes and threads started
    meanwhile inherit the mask, so a Ctrl-C to the process group cannot cut a worker's start-up (a traceback
    per worker, then "Nanny failed to start"); this process gets it when the block ends."""
    import signal
    from multiprocessing import resource_tracker
    resource_tracker.ensure_running()     # started later, it would unblock SIGINT in this thread (SIG_UNBLOCK)
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    except (AttributeError, OSError, ValueError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _ignore_sigint_plugin():
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        def setup(self, worker):
            import signal
            import threading
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreSigint()


def tls_security(scheduler: str | None, ca_file: Path | None = None, cert_file: Path | None = None,
                 key_file: Path | None = None):
    """Dask's TLS settings (``distributed.security.Security``, encryption required) for a ``tls://`` scheduler:
    the CA that signed the scheduler's certificate and this client's certificate and key, or, when none is
    given, Dask's own configuration (``distributed.comm.tls.*`` in ~/.config/dask or DASK_ env variables).
    None for any other scheduler. SpecError naming the option for a file missing or given without tls://."""
    given = {"--tls-ca": ca_file, "--tls-cert": cert_file, "--tls-key": key_file}
    if not (scheduler or "").startswith("tls://"):
        if any(given.values()):
            raise SpecError(f"{', '.join(k for k, v in given.items() if v)}: TLS needs a tls:// scheduler address "
                            f"(--scheduler tls://host:8786), not {scheduler or 'the local cluster'}")
        return None
    for opt, f in given.items():
        if f is not None and not Path(f).is_file():
            raise SpecError(f"{opt}: {f}: no such file")
    from distributed.security import Security
    if not any(given.values()):
        return Security(require_encryption=True)     # Dask's configuration
    return Security(tls_ca_file=str(ca_file) if ca_file else None,
                    tls_client_cert=str(cert_file) if cert_file else None,
                    tls_client_key=str(key_file) if key_file else None, require_encryption=True)


def connect(scheduler: str | None, n_workers: int | None, security=None):
    """A client of the scheduler at ``scheduler`` (with ``security``, :func:`tls_security`, for tls://), or of a
    new local cluster of ``n_workers`` processes. Returns ``(client, cluster)``, ``cluster`` None for a
    scheduler by address.

    Raises
    ------
    BackendError when the scheduler cannot be reached (or dask.distributed is not installed).
    """
    distributed = import_distributed()
    try:
        if scheduler:
            return distributed.Client(scheduler, timeout="20s", security=security), None
        cluster, client = start_local_cluster(n_workers)
        return client, cluster
    except (OSError, TimeoutError) as exc:
        raise BackendError(f"cannot reach the Dask scheduler {scheduler or '(local)'}: {exc}") from None
    except TypeError as exc:           # distributed's word for a tls:// address without TLS settings
        raise BackendError(f"cannot reach the Dask scheduler {scheduler}: {str(exc).splitlines()[0]}; give "
                           f"--tls-ca, --tls-cert and --tls-key (docs/sweeps.md)") from None


def close_quietly(client, cluster) -> None:
    """Close a client and then its cluster (either may be None), logging what fails."""
    for obj in (client, cluster):
        if obj is None:
            continue
        try:
            obj.close(timeout=10) if obj is client else obj.close(timeout=20)
        except Exception:  # noqa: BLE001 - shutting down after Ctrl-C or a lost cluster
            log.debug("closing %s failed", obj, exc_info=True)

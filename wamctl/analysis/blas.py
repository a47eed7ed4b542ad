"""One BLAS thread for the analyses' small dense products (a context manager, or a decorator).

The fits multiply tall, thin matrices: one BLAS thread is fastest, and several threads on a shared machine are
up to ten times slower (OpenBLAS spin-waits). threadpoolctl is optional: without it nothing is limited."""

from __future__ import annotations

from contextlib import contextmanager


@contextmanager
def single_threaded_blas():
    """BLAS limited to one thread inside the block (or the decorated function's call)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield

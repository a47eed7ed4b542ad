"""A sweep's local Dask cluster listens on the loopback interface only (issue 30): scheduler, workers, nannies
and the dashboard."""

from __future__ import annotations

import ipaddress
import os

import psutil
import pytest

from wamctl.experiments.sweep.cluster import close_quietly, start_local_cluster


def listening(pids: set[int]) -> list[tuple[str, int]]:
    out = []
    for c in psutil.net_connections(kind="inet"):
        if c.status == psutil.CONN_LISTEN and c.pid in pids:
            out.append((c.laddr.ip, c.laddr.port))
    return out


def test_no_listening_socket_of_the_cluster_on_a_non_loopback_address():
    pytest.importorskip("distributed")
    cluster, client = start_local_cluster(1)
    try:
        me = psutil.Process(os.getpid())
        pids = {me.pid} | {p.pid for p in me.children(recursive=True)}
        socks = listening(pids)
        dash = client.dashboard_link
        assert len(socks) >= 3, socks                 # scheduler, dashboard, the worker (and its nanny)
        wide = [s for s in socks if not ipaddress.ip_address(s[0]).is_loopback]
        assert wide == [], f"listening beyond loopback: {wide}"
        assert dash.startswith("http://127.0.0.1:")
    finally:
        close_quietly(client, cluster)

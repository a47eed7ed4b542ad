"""A sweep reaches a remote scheduler over TLS (issue 30, item 6): a scheduler that requires encryption
(``tls://``, its certificate signed by a CA made here with openssl) runs the sweep's points for `wamctl sweep
--scheduler tls://... --tls-ca --tls-cert --tls-key`; without the TLS settings the sweep says so in one line."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_runs import run_cli
from test_sweep import tiny

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tls_cluster(tmp_path_factory):
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (it makes the test's certificate)")
    d = tmp_path_factory.mktemp("tls")
    cert, key = d / "cert.pem", d / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=localhost",
                    "-keyout", str(key), "-out", str(cert), "-days", "1"], check=True, capture_output=True)
    from distributed.security import Security
    sec = Security(tls_ca_file=str(cert), tls_scheduler_cert=str(cert), tls_scheduler_key=str(key),
                   tls_worker_cert=str(cert), tls_worker_key=str(key), tls_client_cert=str(cert),
                   tls_client_key=str(key), require_encryption=True)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tls://",
                                  host="127.0.0.1", security=sec, dashboard_address=None) as cluster:
        yield cluster.scheduler_address, cert, key


def test_a_sweep_runs_on_a_tls_scheduler(tmp_path, tls_cluster):
    address, cert, key = tls_cluster
    assert address.startswith("tls://")
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(tiny({"grid": {"seed": [0, 1]}, "reports": False})))
    r = run_cli("sweep", spec, "--out", tmp_path / "out", "--scheduler", address, "--tls-ca", cert,
                "--tls-cert", cert, "--tls-key", key, "--quiet", "--json")
    assert r.code == 0, r.err
    sweep_dir = next((tmp_path / "out").glob("*-sweep"))
    index = json.loads((sweep_dir / "index.json").read_text())
    assert index["counts"]["completed"] == 2
    assert json.loads((sweep_dir / "sweep.json").read_text())["sessions"][-1]["scheduler"] == address


def test_without_the_tls_settings_or_with_them_for_tcp_one_line(tmp_path, tls_cluster):
    address, cert, key = tls_cluster
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(tiny({"grid": {"seed": [0, 1]}, "reports": False})))
    # no settings given and none in Dask's configuration: subprocess, so that this test's settings stay its own
    r = subprocess.run([sys.executable, "-m", "wamctl", "sweep", str(spec), "--out", str(tmp_path / "a"),
                        "--scheduler", address, "--quiet"], capture_output=True, text=True, timeout=120, cwd=ROOT,
                       env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)})
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "--tls-ca" in r.stderr, r.stderr
    r = run_cli("sweep", spec, "--out", tmp_path / "b", "--scheduler", "tcp://127.0.0.1:1", "--tls-ca", cert)
    assert r.code == 2 and "TLS needs a tls:// scheduler address" in r.err, r.err
    r = run_cli("sweep", spec, "--out", tmp_path / "c", "--scheduler", address, "--tls-ca", tmp_path / "none.pem")
    assert r.code == 2 and "--tls-ca" in r.err and "no such file" in r.err, r.err

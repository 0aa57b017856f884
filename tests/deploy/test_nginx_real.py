"""nginx's configuration (``deploy/nginx/nginx.conf``) in a real nginx in front of two
real fleet-server processes on loopback, when an ``nginx`` binary is installed (skipped
otherwise): HTTPS and a ``wss://`` WebSocket through it, plain HTTP redirected, no
token in its access log, each replica answering some of the calls."""

from __future__ import annotations

import json
import re
import shutil
import signal
import ssl
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect

from tests.agent.procs import ADMIN_TOKEN, ServerProcess, free_port, wait_until
from tests.deploy.files import NGINX_CONF, SERVERS


def _nginx_version(binary: str) -> tuple[int, ...]:
    out = subprocess.run([binary, "-v"], capture_output=True, text=True, check=True).stderr
    found = re.search(r"nginx/(\d+)\.(\d+)\.(\d+)", out)
    assert found is not None, out
    return tuple(int(x) for x in found.groups())


@pytest.fixture
def two_servers(tmp_path: Path) -> Iterator[list[ServerProcess]]:
    servers = []
    try:
        for name in SERVERS:
            (tmp_path / name).mkdir()
            server = ServerProcess(tmp_path / name)
            server.start()
            servers.append(server)
        yield servers
    finally:
        for server in servers:
            server.stop()


@pytest.mark.slow
def test_the_nginx_configuration_in_a_real_nginx(
    tmp_path: Path, two_servers: list[ServerProcess]
) -> None:
    binary = shutil.which("nginx", path="/usr/sbin:/usr/local/sbin:/usr/bin:/usr/local/bin")
    if binary is None:
        pytest.skip("no nginx binary on this machine (apt-get install nginx-light)")
    tls = tmp_path / "tls"
    tls.mkdir()
    # the self-signed pair docs/deploy.md tells how to make, for 127.0.0.1
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
         "-keyout", str(tls / "fleet.key"), "-out", str(tls / "fleet.crt")],
        check=True, capture_output=True,
    )  # fmt: skip
    https_port, http_port = free_port(), free_port()
    conf = NGINX_CONF.read_text()
    for name, server in zip(SERVERS, two_servers, strict=True):
        conf = conf.replace(f"{name}:8000", f"127.0.0.1:{server.port}")
    conf = conf.replace("/etc/nginx/tls/", f"{tls}/")
    conf = conf.replace("/var/log/nginx/access.log", str(tmp_path / "access.log"))
    conf = conf.replace("listen 443 ssl;", f"listen 127.0.0.1:{https_port} ssl;")
    conf = conf.replace("listen 80;", f"listen 127.0.0.1:{http_port};")
    conf = re.sub(r"\n\s*listen \[::\]:\d+[^;]*;", "", conf)
    if _nginx_version(binary) < (1, 25, 1):  # `http2 on;` is newer than this nginx
        conf = conf.replace("http2 on;", "")
    conf = conf.replace("worker_processes auto;", "worker_processes 1;")
    conf = conf.replace("/var/log/nginx/error.log", str(tmp_path / "error.log"))
    temp = " ".join(
        f"{kind}_temp_path {tmp_path / kind};"
        for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")
    )
    conf = conf.replace("http {", "http {\n    " + temp, 1)
    (tmp_path / "nginx.conf").write_text(conf)
    args = [binary, "-p", str(tmp_path), "-e", str(tmp_path / "error.log")]
    args += ["-c", str(tmp_path / "nginx.conf"), "-g", f"daemon off; pid {tmp_path}/nginx.pid;"]
    checked = subprocess.run([*args, "-t"], capture_output=True, text=True, check=False)
    assert checked.returncode == 0, checked.stderr
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        base = f"https://127.0.0.1:{https_port}"
        cert = str(tls / "fleet.crt")

        def answers() -> bool:
            assert proc.poll() is None, (tmp_path / "error.log").read_text()
            return httpx.get(f"{base}/healthz", verify=ssl.create_default_context(cafile=cert),
                             timeout=2).status_code == 200  # fmt: skip

        wait_until(answers, "nginx to answer on TLS")
        ctx = ssl.create_default_context(cafile=cert)
        with httpx.Client(base_url=base, verify=ctx, timeout=10) as client:
            ready = client.get("/readyz")
            assert ready.status_code == 200 and ready.json()["ready"] is True
            assert client.get("/metrics").status_code == 404
            auth = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
            for _ in range(6):
                assert client.get("/api/vehicles", headers=auth).status_code == 200
        plain = httpx.get(f"http://127.0.0.1:{http_port}/api/vehicles?token=x", timeout=5)
        assert plain.status_code == 301
        assert plain.headers["location"].startswith("https://")
        # a WebSocket through TLS and the proxy, the token on its URL
        wss = f"wss://127.0.0.1:{https_port}"
        with connect(f"{wss}/ws/client?token={ADMIN_TOKEN}", ssl=ctx) as ws:
            ws.send(json.dumps({"op": "subscribe", "id": "1", "topics": ["fleet"]}))
            assert json.loads(ws.recv(timeout=10))["op"] == "ack"
        with connect(f"{wss}/ws/client", ssl=ctx, additional_headers=auth) as ws:
            ws.send(json.dumps({"op": "subscribe", "id": "2", "topics": ["fleet"]}))
            assert json.loads(ws.recv(timeout=10))["op"] == "ack"
    finally:
        proc.send_signal(signal.SIGQUIT)  # graceful: finish what is open, write the logs
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=15)
    access = (tmp_path / "access.log").read_text()
    assert "/ws/client" in access and "/api/vehicles" in access
    assert ADMIN_TOKEN not in access and "token=" not in access
    # round robin: each replica answered some of them
    for server in two_servers:
        counts = httpx.get(f"{server.url}/metrics", timeout=5).text
        assert 'route="/api/vehicles",status="200"' in counts, server.url

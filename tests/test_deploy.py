"""The deployment past one machine (deploy/, docs/deploy.md), checked as far as this machine
allows, and the server's JSON log lines.

No container engine runs here: ``deploy/compose.cluster.yml`` and ``docker-compose.yml``
are parsed and checked against each other, against ``deploy/nginx/nginx.conf``,
``deploy/mongo/init-replica-set.js`` and the server's settings, never started. The nginx
configuration itself runs in a real nginx in front of two real fleet-server processes
when an ``nginx`` binary is installed (skipped otherwise). The JSON logs come from a real
fleet-server process.
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import ssl
import subprocess
from collections.abc import Iterator
from ipaddress import ip_address, ip_network
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import httpx
import pytest
import yaml
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from server.logs import REDACTED, JsonLines
from server.settings import Settings
from tests.agent.procs import ADMIN_TOKEN, Fleet, ServerProcess, free_port, wait_until

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
CLUSTER = DEPLOY / "compose.cluster.yml"
SINGLE = ROOT / "docker-compose.yml"
NGINX_CONF = DEPLOY / "nginx" / "nginx.conf"
RS_INIT = DEPLOY / "mongo" / "init-replica-set.js"
SERVERS = ("fleet-1", "fleet-2")


def _compose(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())


@pytest.fixture(scope="module")
def cluster() -> dict[str, Any]:
    return _compose(CLUSTER)


@pytest.fixture(scope="module")
def services(cluster: dict[str, Any]) -> dict[str, Any]:
    return cluster["services"]


def _env(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment", {})
    if isinstance(env, list):  # the KEY=VALUE form
        env = dict(item.split("=", 1) for item in env)
    return {k: str(v) for k, v in env.items()}


def _replica_set() -> tuple[str, list[str]]:
    """The set's name and its members' host:port, as the initiation script gives them."""
    text = RS_INIT.read_text()
    config = text[text.index("const config") :]
    name = re.search(r'_id:\s*"([^"]+)"', config)
    assert name is not None
    return name.group(1), re.findall(r'host:\s*"([^"]+)"', config)


# ---- the nginx configuration, read as blocks ---------------------------------------------


def _nginx_tokens(text: str) -> list[str]:
    text = re.sub(r"#[^\n]*", "", text)
    return re.findall(r"'[^']*'|\"[^\"]*\"|[{};]|[^\s{};]+", text)


def _nginx_parse(tokens: list[str], i: int = 0) -> tuple[list[Any], int]:
    """nginx's syntax as nested lists: ``[name, [args], [children] | None]``."""
    out: list[Any] = []
    words: list[str] = []
    while i < len(tokens):
        tok = tokens[i]
        i += 1
        if tok == ";":
            out.append([words[0], words[1:], None])
            words = []
        elif tok == "{":
            children, i = _nginx_parse(tokens, i)
            out.append([words[0], words[1:], children])
            words = []
        elif tok == "}":
            return out, i
        else:
            words.append(tok.strip("'\"") if tok[0] in "'\"" else tok)
    return out, i


@pytest.fixture(scope="module")
def nginx_main() -> list[Any]:
    tree, _ = _nginx_parse(_nginx_tokens(NGINX_CONF.read_text()))
    return tree


@pytest.fixture(scope="module")
def nginx(nginx_main: list[Any]) -> list[Any]:
    """The ``http`` block."""
    ((http,),) = [[d[2]] for d in nginx_main if d[0] == "http"]
    return http


def _all(block: list[Any], name: str) -> list[list[Any]]:
    return [d for d in block if d[0] == name]


def _args(block: list[Any], name: str) -> list[list[str]]:
    return [d[1] for d in _all(block, name)]


def _headers(location: list[Any]) -> dict[str, str]:
    return {a[0].lower(): " ".join(a[1:]) for a in _args(location, "proxy_set_header")}


def _tls_server(nginx: list[Any]) -> list[Any]:
    (server,) = [
        d[2] for d in _all(nginx, "server") if any("443" in a[0] for a in _args(d[2], "listen"))
    ]
    return server


def _locations(server: list[Any]) -> dict[str, list[Any]]:
    return {" ".join(d[1]): d[2] for d in _all(server, "location")}


# ---- the compose files ----------------------------------------------------------------------


def test_single_machine_file_still_runs_one_server_and_logs_json() -> None:
    compose = _compose(SINGLE)
    services = compose["services"]
    assert set(services) == {"mongo", "redis", "server"}
    assert all("profiles" not in s for s in services.values())  # plain `docker compose up`
    assert _env(services["server"])["FLEET_LOG_FORMAT"] == "json"


def test_both_replicas_share_one_replica_set_and_one_redis(services: dict[str, Any]) -> None:
    envs = [_env(services[name]) for name in SERVERS]
    assert envs[0] == envs[1]
    env = envs[0]
    url = urlsplit(env["FLEET_MONGO_URL"])
    assert url.scheme == "mongodb"
    assert url.username is None and url.password is None
    name, members = _replica_set()
    assert parse_qs(url.query)["replicaSet"] == [name]
    assert url.netloc.split(",") == members  # every member named: the driver finds the primary
    assert "directConnection" not in url.query
    redis = urlsplit(env["FLEET_REDIS_URL"])
    assert redis.scheme == "redis" and redis.hostname == "redis" and "redis" in services
    assert env["FLEET_STORE_WRITE_CONCERN"] == "majority"
    for name in SERVERS:
        build = services[name]["build"]
        assert (CLUSTER.parent / build["context"] / build["dockerfile"]).resolve() == (
            ROOT / "Dockerfile"
        )
        assert "ports" not in services[name]  # reached through the proxy only


def test_mongo_members_and_the_initiation_agree(services: dict[str, Any]) -> None:
    name, members = _replica_set()
    assert len(members) == 3
    volumes: set[str] = set()
    for member in members:
        host, port = member.split(":")
        assert port == "27017"
        service = services[host]
        assert service["image"].startswith("mongo:")
        command = service["command"]
        assert command[command.index("--replSet") + 1] == name
        assert "--bind_ip_all" in command
        (volume,) = service["volumes"]
        assert volume.endswith(":/data/db")
        volumes.add(volume.split(":")[0])
    assert len(volumes) == 3  # each member its own data
    init = services["mongo-init"]
    assert init["restart"] == "no"
    assert {m.split(":")[0] for m in members} == set(init["depends_on"])
    (mount,) = init["volumes"]
    source, target, _ro = mount.split(":")
    assert (CLUSTER.parent / source).resolve() == RS_INIT
    assert init["command"][init["command"].index("--file") + 1] == target
    assert init["command"][init["command"].index("--host") + 1] in services
    assert "rs.initiate(config)" in RS_INIT.read_text()


def test_every_service_the_servers_wait_for_is_checked(services: dict[str, Any]) -> None:
    def ready(name: str, condition: str) -> None:
        service = services[name]
        if condition == "service_healthy":
            assert "healthcheck" in service, name
        else:  # a one-shot: it runs once what it waits for is healthy
            assert condition == "service_completed_successfully", name
            for dep, how in service["depends_on"].items():
                assert how["condition"] == "service_healthy", (name, dep)
                assert "healthcheck" in services[dep], dep

    for server in SERVERS:
        deps = services[server]["depends_on"]
        assert {"mongo-init", "redis"} <= set(deps)
        for dep, how in deps.items():
            ready(dep, how["condition"])
        check = " ".join(services[server]["healthcheck"]["test"])
        assert "http://127.0.0.1:8000/readyz" in check and "!= 200" in check
    proxy = services["proxy"]["depends_on"]
    assert set(proxy) == set(SERVERS)
    assert {how["condition"] for how in proxy.values()} == {"service_healthy"}


def test_proxy_terminates_tls_and_passes_websocket_upgrades(
    services: dict[str, Any], cluster: dict[str, Any], nginx: list[Any]
) -> None:
    proxy = services["proxy"]
    assert "443:443" in proxy["ports"]
    mounts = dict(v.rsplit(":", 2)[:2] for v in proxy["volumes"])
    assert (CLUSTER.parent / "nginx/nginx.conf").resolve() == NGINX_CONF
    assert mounts["./nginx/nginx.conf"] == "/etc/nginx/nginx.conf"  # the whole of it
    assert mounts["${FLEET_TLS_DIR:-./tls}"] == "/etc/nginx/tls"

    server = _tls_server(nginx)
    assert ["443", "ssl"] in _args(server, "listen")
    for directive in ("ssl_certificate", "ssl_certificate_key"):
        ((path,),) = _args(server, directive)
        assert path.startswith("/etc/nginx/tls/")  # the operator's files, mounted
    ((*protocols,),) = _args(server, "ssl_protocols")
    assert set(protocols) <= {"TLSv1.2", "TLSv1.3"}

    # Connection: upgrade when the client asked for one
    ((variable, result, block),) = [(*d[1], d[2]) for d in _all(nginx, "map")]
    assert (variable, result) == ("$http_upgrade", "$connection_upgrade")
    assert ["default", "upgrade"] in [[d[0], *d[1]] for d in block]

    locations = _locations(server)
    ws = locations["/ws/"]
    assert _args(ws, "proxy_http_version") == [["1.1"]]
    headers = _headers(ws)
    assert headers["upgrade"] == "$http_upgrade"
    assert headers["connection"] == "$connection_upgrade"
    ((timeout,),) = _args(ws, "proxy_read_timeout")
    assert timeout.endswith("h") or int(timeout.rstrip("s")) >= 60  # idle sockets stay open

    # every replica behind every upstream, on the port it listens on
    port = _env(services["fleet-1"])["FLEET_PORT"]
    upstreams = {d[1][0]: d[2] for d in _all(nginx, "upstream")}
    for block in upstreams.values():
        assert sorted(a[0] for a in _args(block, "server")) == [f"{s}:{port}" for s in SERVERS]
    for path, location in locations.items():
        if _args(location, "proxy_pass"):
            ((target,),) = _args(location, "proxy_pass")
            assert target.removeprefix("http://") in upstreams, path
            # one X-Forwarded-For entry, the real peer: a client cannot forge its address
            assert _headers(location)["x-forwarded-for"] == "$remote_addr", path
            assert _headers(location)["x-forwarded-proto"] == "$scheme", path
            ((read_timeout,),) = _args(location, "proxy_read_timeout")
            assert read_timeout.endswith("h") or int(read_timeout.rstrip("s")) > 30  # long polls
    assert "$http_authorization" in _args(upstreams["fleet_servers_by_token"], "hash")[0]
    assert _args(locations["/upper/"], "proxy_pass") == [["http://fleet_servers_by_token"]]

    # uvicorn trusts X-Forwarded-For from the proxy's fixed address only
    (subnet,) = [c["subnet"] for c in cluster["networks"]["fleet"]["ipam"]["config"]]
    proxy_ip = proxy["networks"]["fleet"]["ipv4_address"]
    assert ip_address(proxy_ip) in ip_network(subnet)
    for name in SERVERS:
        assert _env(services[name])["FORWARDED_ALLOW_IPS"] == proxy_ip

    # plain HTTP only redirects
    (plain,) = [d[2] for d in _all(nginx, "server") if d[2] is not server]
    assert _args(plain, "return") == [["301", "https://$host$request_uri"]]


def test_the_proxy_has_room_for_many_sockets(
    services: dict[str, Any], nginx_main: list[Any]
) -> None:
    ((events,),) = [[d[2]] for d in nginx_main if d[0] == "events"]
    ((connections,),) = _args(events, "worker_connections")
    ((files,),) = _args(nginx_main, "worker_rlimit_nofile")
    assert int(connections) >= 16_384  # two per proxied socket
    assert int(files) >= int(connections)
    limit = services["proxy"]["ulimits"]["nofile"]
    assert limit["soft"] >= int(files) and limit["hard"] >= int(files)


def test_no_log_of_the_proxy_holds_a_query_string_or_a_header(nginx: list[Any]) -> None:
    formats = {d[1][0]: " ".join(d[1][1:]) for d in _all(nginx, "log_format")}
    for name, fmt in formats.items():
        for leak in ("$request ", "$request_uri", "$args", "$query_string", "$http_", "$arg_"):
            assert leak not in fmt + " ", (name, leak)
    for server in [d[2] for d in _all(nginx, "server")]:
        for args in _args(server, "access_log"):
            assert args[0] == "off" or args[1] in formats  # never nginx's own 'combined'


def test_no_secret_is_written_in_the_files() -> None:
    for path in (SINGLE, CLUSTER):
        for name, service in _compose(path)["services"].items():
            for key, value in _env(service).items():
                if re.search(r"TOKEN|SECRET|PASSWORD|PASSWD|_KEY$", key):
                    assert re.fullmatch(r"\$\{[A-Z_]+(:\?[^}]*)?\}", value), (path, name, key)
                if "://" in value:
                    assert urlsplit(value).password is None, (path, name, key)
    for path in [*DEPLOY.rglob("*"), SINGLE]:
        if path.is_file():
            assert "PRIVATE KEY" not in path.read_text(errors="replace"), path
    ignored = subprocess.run(
        ["git", "check-ignore", "-q", "deploy/tls/fleet.key"], cwd=ROOT, check=False
    )
    assert ignored.returncode == 0, "deploy/tls/ must be in .gitignore"


def test_every_fleet_variable_the_compose_files_set_is_a_setting() -> None:
    settings = set(Settings.model_fields)
    seen = set()
    for path in (SINGLE, CLUSTER):
        for service in _compose(path)["services"].values():
            for key in _env(service):
                if key.startswith("FLEET_"):
                    seen.add(key)
                    assert key.removeprefix("FLEET_").lower() in settings, (path, key)
    assert {"FLEET_LOG_FORMAT", "FLEET_MONGO_URL", "FLEET_REDIS_URL"} <= seen


# ---- JSON log lines -----------------------------------------------------------------------


def test_json_lines_carry_the_exception_and_no_token() -> None:
    import logging
    import sys

    from server.logs import RedactSecrets

    try:
        raise RuntimeError("refused Bearer fct_abcdefghijklmnop")
    except RuntimeError:
        record = logging.LogRecord(
            "fleet.x", logging.ERROR, __file__, 1, "failed for %s", ("?token=s3cret",),
            sys.exc_info(),
        )  # fmt: skip
    record.extra_field = {"token_url": "/ws/client?token=s3cret"}
    RedactSecrets().filter(record)
    line = json.loads(JsonLines().format(record))
    assert list(line)[:4] == ["time", "level", "logger", "message"]
    assert line["level"] == "ERROR" and line["logger"] == "fleet.x"
    assert line["message"] == f"failed for ?token={REDACTED}"
    assert "RuntimeError: refused Bearer [redacted]" in line["exception"]
    assert line["extra_field"] == {"token_url": f"/ws/client?token={REDACTED}"}
    assert "s3cret" not in json.dumps(line) and "fct_abc" not in json.dumps(line)


@pytest.mark.slow
def test_a_real_server_with_json_logs_writes_json_lines_without_tokens(tmp_path: Path) -> None:
    server = ServerProcess(tmp_path)
    server.env.update(FLEET_LOG_FORMAT="json", FLEET_LOG_LEVEL="info")
    server.start()
    ws_url = server.url.replace("http://", "ws://")
    try:
        fleet = Fleet(server)
        fleet.call("GET", "/api/vehicles")  # the admin token in a header
        vehicle_token = fleet.create_vehicle("usv-log")
        # tokens on the URL: uvicorn logs each socket's path with its query string
        with connect(f"{ws_url}/ws/client?token={ADMIN_TOKEN}") as ws:
            ws.send(json.dumps({"op": "subscribe", "id": "1", "topics": ["fleet"]}))
            assert json.loads(ws.recv(timeout=10))["op"] == "ack"
        with connect(f"{ws_url}/ws/vehicle?token={vehicle_token}") as ws:
            pass
        wrong = "fct_" + "x" * 40
        with connect(f"{ws_url}/ws/client?token={wrong}") as ws:  # accepted, then closed
            with pytest.raises(ConnectionClosed) as closed:
                ws.recv(timeout=10)
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
    finally:
        server.stop()
    text = server.log.read_text()
    lines = [json.loads(line) for line in text.splitlines()]  # every line is JSON
    assert lines
    for line in lines:
        assert {"time", "level", "logger", "message"} <= set(line), line
    messages = [line["message"] for line in lines]
    assert any(f"/ws/client?token={REDACTED}" in m for m in messages), messages
    assert any(f"/ws/vehicle?token={REDACTED}" in m for m in messages), messages
    for secret in (ADMIN_TOKEN, vehicle_token, wrong):
        assert secret not in text


# ---- the nginx configuration in a real nginx ----------------------------------------------


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

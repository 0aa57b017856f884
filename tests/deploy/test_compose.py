"""The compose files (``docker-compose.yml``, ``deploy/compose.cluster.yml``), parsed and
checked against each other, against ``deploy/mongo/init-replica-set.js`` and the
server's settings, never started (no container engine runs here): one server on one
machine; two replicas sharing one replica set and one Redis; the set's members as
initiated; every service the servers wait for checked; no secret written in them."""

from __future__ import annotations

import re
import subprocess
from typing import Any
from urllib.parse import parse_qs, urlsplit

from server.settings import Settings
from tests.deploy.files import (
    CLUSTER,
    DEPLOY,
    ROOT,
    RS_INIT,
    SERVERS,
    SINGLE,
    env_of,
    read_compose,
    replica_set,
)


def test_single_machine_file_still_runs_one_server_and_logs_json() -> None:
    compose = read_compose(SINGLE)
    services = compose["services"]
    assert set(services) == {"mongo", "redis", "server"}
    assert all("profiles" not in s for s in services.values())  # plain `docker compose up`
    assert env_of(services["server"])["FLEET_LOG_FORMAT"] == "json"


def test_both_replicas_share_one_replica_set_and_one_redis(services: dict[str, Any]) -> None:
    envs = [env_of(services[name]) for name in SERVERS]
    assert envs[0] == envs[1]
    env = envs[0]
    url = urlsplit(env["FLEET_MONGO_URL"])
    assert url.scheme == "mongodb"
    assert url.username is None and url.password is None
    name, members = replica_set()
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
    name, members = replica_set()
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


def test_no_secret_is_written_in_the_files() -> None:
    for path in (SINGLE, CLUSTER):
        for name, service in read_compose(path)["services"].items():
            for key, value in env_of(service).items():
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
        for service in read_compose(path)["services"].values():
            for key in env_of(service):
                if key.startswith("FLEET_"):
                    seen.add(key)
                    assert key.removeprefix("FLEET_").lower() in settings, (path, key)
    assert {"FLEET_LOG_FORMAT", "FLEET_MONGO_URL", "FLEET_REDIS_URL"} <= seen

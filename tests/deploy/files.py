"""The deployment's files as the tests read them (``tests/deploy/``): where they are, the
compose files' services and environments, the replica set's initiation, and nginx's
configuration as nested blocks."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
CLUSTER = DEPLOY / "compose.cluster.yml"
SINGLE = ROOT / "docker-compose.yml"
NGINX_CONF = DEPLOY / "nginx" / "nginx.conf"
RS_INIT = DEPLOY / "mongo" / "init-replica-set.js"
SERVERS = ("fleet-1", "fleet-2")


def read_compose(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())


def env_of(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment", {})
    if isinstance(env, list):  # the KEY=VALUE form
        env = dict(item.split("=", 1) for item in env)
    return {k: str(v) for k, v in env.items()}


def replica_set() -> tuple[str, list[str]]:
    """The set's name and its members' host:port, as the initiation script gives them."""
    text = RS_INIT.read_text()
    config = text[text.index("const config") :]
    name = re.search(r'_id:\s*"([^"]+)"', config)
    assert name is not None
    return name.group(1), re.findall(r'host:\s*"([^"]+)"', config)


# ---- the nginx configuration, read as blocks ---------------------------------------------


def nginx_tokens(text: str) -> list[str]:
    text = re.sub(r"#[^\n]*", "", text)
    return re.findall(r"'[^']*'|\"[^\"]*\"|[{};]|[^\s{};]+", text)


def nginx_parse(tokens: list[str], i: int = 0) -> tuple[list[Any], int]:
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
            children, i = nginx_parse(tokens, i)
            out.append([words[0], words[1:], children])
            words = []
        elif tok == "}":
            return out, i
        else:
            words.append(tok.strip("'\"") if tok[0] in "'\"" else tok)
    return out, i


def directives(block: list[Any], name: str) -> list[list[Any]]:
    return [d for d in block if d[0] == name]


def args_of(block: list[Any], name: str) -> list[list[str]]:
    return [d[1] for d in directives(block, name)]


def headers_of(location: list[Any]) -> dict[str, str]:
    return {a[0].lower(): " ".join(a[1:]) for a in args_of(location, "proxy_set_header")}


def tls_server(nginx: list[Any]) -> list[Any]:
    (server,) = [
        d[2]
        for d in directives(nginx, "server")
        if any("443" in a[0] for a in args_of(d[2], "listen"))
    ]
    return server


def locations_of(server: list[Any]) -> dict[str, list[Any]]:
    return {" ".join(d[1]): d[2] for d in directives(server, "location")}

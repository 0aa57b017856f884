"""nginx's configuration (``deploy/nginx/nginx.conf``), read as blocks and checked against
the cluster's compose file: TLS ends on 443 and WebSocket upgrades pass, every replica
is behind every upstream, the proxy has room for many sockets, and no log of it holds
a query string or a header."""

from __future__ import annotations

from ipaddress import ip_address, ip_network
from typing import Any

from tests.deploy.files import (
    CLUSTER,
    NGINX_CONF,
    SERVERS,
    args_of,
    directives,
    env_of,
    headers_of,
    locations_of,
    tls_server,
)


def test_proxy_terminates_tls_and_passes_websocket_upgrades(
    services: dict[str, Any], cluster: dict[str, Any], nginx: list[Any]
) -> None:
    proxy = services["proxy"]
    assert "443:443" in proxy["ports"]
    mounts = dict(v.rsplit(":", 2)[:2] for v in proxy["volumes"])
    assert (CLUSTER.parent / "nginx/nginx.conf").resolve() == NGINX_CONF
    assert mounts["./nginx/nginx.conf"] == "/etc/nginx/nginx.conf"  # the whole of it
    assert mounts["${FLEET_TLS_DIR:-./tls}"] == "/etc/nginx/tls"

    server = tls_server(nginx)
    assert ["443", "ssl"] in args_of(server, "listen")
    for directive in ("ssl_certificate", "ssl_certificate_key"):
        ((path,),) = args_of(server, directive)
        assert path.startswith("/etc/nginx/tls/")  # the operator's files, mounted
    ((*protocols,),) = args_of(server, "ssl_protocols")
    assert set(protocols) <= {"TLSv1.2", "TLSv1.3"}

    # Connection: upgrade when the client asked for one
    ((variable, result, block),) = [(*d[1], d[2]) for d in directives(nginx, "map")]
    assert (variable, result) == ("$http_upgrade", "$connection_upgrade")
    assert ["default", "upgrade"] in [[d[0], *d[1]] for d in block]

    locations = locations_of(server)
    ws = locations["/ws/"]
    assert args_of(ws, "proxy_http_version") == [["1.1"]]
    headers = headers_of(ws)
    assert headers["upgrade"] == "$http_upgrade"
    assert headers["connection"] == "$connection_upgrade"
    ((timeout,),) = args_of(ws, "proxy_read_timeout")
    assert timeout.endswith("h") or int(timeout.rstrip("s")) >= 60  # idle sockets stay open

    # every replica behind every upstream, on the port it listens on
    port = env_of(services["fleet-1"])["FLEET_PORT"]
    upstreams = {d[1][0]: d[2] for d in directives(nginx, "upstream")}
    for block in upstreams.values():
        assert sorted(a[0] for a in args_of(block, "server")) == [f"{s}:{port}" for s in SERVERS]
    for path, location in locations.items():
        if args_of(location, "proxy_pass"):
            ((target,),) = args_of(location, "proxy_pass")
            assert target.removeprefix("http://") in upstreams, path
            # one X-Forwarded-For entry, the real peer: a client cannot forge its address
            assert headers_of(location)["x-forwarded-for"] == "$remote_addr", path
            assert headers_of(location)["x-forwarded-proto"] == "$scheme", path
            ((read_timeout,),) = args_of(location, "proxy_read_timeout")
            assert read_timeout.endswith("h") or int(read_timeout.rstrip("s")) > 30  # long polls
    assert "$http_authorization" in args_of(upstreams["fleet_servers_by_token"], "hash")[0]
    assert args_of(locations["/upper/"], "proxy_pass") == [["http://fleet_servers_by_token"]]

    # uvicorn trusts X-Forwarded-For from the proxy's fixed address only
    (subnet,) = [c["subnet"] for c in cluster["networks"]["fleet"]["ipam"]["config"]]
    proxy_ip = proxy["networks"]["fleet"]["ipv4_address"]
    assert ip_address(proxy_ip) in ip_network(subnet)
    for name in SERVERS:
        assert env_of(services[name])["FORWARDED_ALLOW_IPS"] == proxy_ip

    # plain HTTP only redirects
    (plain,) = [d[2] for d in directives(nginx, "server") if d[2] is not server]
    assert args_of(plain, "return") == [["301", "https://$host$request_uri"]]


def test_the_proxy_has_room_for_many_sockets(
    services: dict[str, Any], nginx_main: list[Any]
) -> None:
    ((events,),) = [[d[2]] for d in nginx_main if d[0] == "events"]
    ((connections,),) = args_of(events, "worker_connections")
    ((files,),) = args_of(nginx_main, "worker_rlimit_nofile")
    assert int(connections) >= 16_384  # two per proxied socket
    assert int(files) >= int(connections)
    limit = services["proxy"]["ulimits"]["nofile"]
    assert limit["soft"] >= int(files) and limit["hard"] >= int(files)


def test_no_log_of_the_proxy_holds_a_query_string_or_a_header(nginx: list[Any]) -> None:
    formats = {d[1][0]: " ".join(d[1][1:]) for d in directives(nginx, "log_format")}
    for name, fmt in formats.items():
        for leak in ("$request ", "$request_uri", "$args", "$query_string", "$http_", "$arg_"):
            assert leak not in fmt + " ", (name, leak)
    for server in [d[2] for d in directives(nginx, "server")]:
        for args in args_of(server, "access_log"):
            assert args[0] == "off" or args[1] in formats  # never nginx's own 'combined'

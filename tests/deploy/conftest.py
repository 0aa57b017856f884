"""Fixtures of the deployment's tests: the cluster's compose file and nginx's
configuration, each read once a module (``files.py``)."""

from __future__ import annotations

from typing import Any

import pytest

from tests.deploy.files import CLUSTER, NGINX_CONF, nginx_parse, nginx_tokens, read_compose


@pytest.fixture(scope="module")
def cluster() -> dict[str, Any]:
    return read_compose(CLUSTER)


@pytest.fixture(scope="module")
def services(cluster: dict[str, Any]) -> dict[str, Any]:
    return cluster["services"]


@pytest.fixture(scope="module")
def nginx_main() -> list[Any]:
    tree, _ = nginx_parse(nginx_tokens(NGINX_CONF.read_text()))
    return tree


@pytest.fixture(scope="module")
def nginx(nginx_main: list[Any]) -> list[Any]:
    """The ``http`` block."""
    ((http,),) = [[d[2]] for d in nginx_main if d[0] == "http"]
    return http

"""A failsafe policy set on one replica while the vehicle waits in a long poll on the
other (as test_replicas_shared_store: two apps, one store, a real redis-server)."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from server.settings import Settings
from tests.bus.conftest import RedisServer
from tests.bus.test_replicas_shared_store import two_replicas
from tests.factories import make_vehicle
from tests.server.test_failsafe_long_poll import _policy_set_during, _started

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_a_policy_set_on_another_replica_ends_the_long_poll(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with two_replicas(make_settings, redis_server) as (api_a, api_b, _):
        vid, vh = await make_vehicle(api_a)
        iid = await _started(api_b, vid, vh)
        answer = await _policy_set_during(api_b, api_a, vid, iid, vh)
        assert answer["failsafe"]["action"] == "stop"

"""The store fixtures of tests/stores.py: FerretDB through PyMongo's AsyncMongoClient (or
the server of FLEET_TEST_MONGO_URL), a private FerretDB stopped, killed and started
again, and the ``store_backend`` parametrisation reaching ``make_settings``."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymongo import AsyncMongoClient
from pymongo.errors import AutoReconnect, DuplicateKeyError, ServerSelectionTimeoutError

from server.settings import Settings
from tests.stores import FerretDB, MongoTarget, StoreBackend, require_ferretdb_binary


async def test_ping_insert_and_find(mongo_url: MongoTarget) -> None:
    client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(
        mongo_url.url, serverSelectionTimeoutMS=5000
    )
    try:
        assert (await client.admin.command("ping"))["ok"] == 1
        things = client[mongo_url.db_name]["things"]
        await things.insert_one({"_id": "a", "n": 1})
        assert await things.find_one({"_id": "a"}) == {"_id": "a", "n": 1}
    finally:
        await client.close()


async def test_a_unique_index_refuses_a_duplicate(mongo_url: MongoTarget) -> None:
    client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(
        mongo_url.url, serverSelectionTimeoutMS=5000
    )
    try:
        users = client[mongo_url.db_name]["users"]
        await users.create_index("name", unique=True)
        await users.insert_one({"name": "ana"})
        with pytest.raises(DuplicateKeyError):
            await users.insert_one({"name": "ana"})
        assert await users.count_documents({}) == 1
    finally:
        await client.close()


async def test_stop_and_start_on_the_same_port_keep_the_data(
    make_ferretdb: Callable[[], FerretDB],
) -> None:
    store = make_ferretdb()
    port = store.port
    client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(
        store.url, serverSelectionTimeoutMS=5000
    )
    try:
        await client.fleet.things.insert_one({"_id": 1, "kept": True})
        await asyncio.to_thread(store.stop)
        assert not store.running
        await asyncio.to_thread(store.start)
        assert store.port == port
        # The same client reconnects to the restarted server, which reads the same files.
        assert await client.fleet.things.find_one({"_id": 1}) == {"_id": 1, "kept": True}
    finally:
        await client.close()


async def test_a_killed_store_fails_the_client_fast(
    make_ferretdb: Callable[[], FerretDB],
) -> None:
    store = make_ferretdb()
    client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(
        store.url, serverSelectionTimeoutMS=500, connectTimeoutMS=500
    )
    try:
        await client.fleet.things.insert_one({"_id": 1})
        await asyncio.to_thread(store.kill)
        started = time.monotonic()
        # The first operation meets the dead pooled connection: PyMongo raises that error
        # (AutoReconnect) even where it retries the read, and forgets the server.
        with pytest.raises(AutoReconnect):
            await client.fleet.things.find_one({"_id": 1})
        # From then on, server selection gives up after serverSelectionTimeoutMS.
        with pytest.raises(ServerSelectionTimeoutError):
            await client.fleet.things.find_one({"_id": 1})
        assert time.monotonic() - started < 5
    finally:
        await client.close()


async def test_make_settings_follow_the_store_backend(
    store_backend: StoreBackend, make_settings: Callable[..., Settings]
) -> None:
    settings = make_settings()
    assert settings.embedded is (store_backend.name == "embedded")
    if store_backend.name == "embedded":
        return
    assert settings.mongo_url is not None
    assert settings.db_name == store_backend.settings["db_name"]
    # The settings reach the server. No app here: on the real driver under Python 3.11 the
    # app's shutdown can hang for a background task's 60 s sleep (a cancellation lost in
    # asyncio.wait_for inside PyMongo), which is the server's to mend, not this module's.
    client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(
        settings.mongo_url.get_secret_value(), serverSelectionTimeoutMS=5000
    )
    try:
        await client[settings.db_name]["probe"].insert_one({"_id": 1})
        assert await client[settings.db_name]["probe"].count_documents({}) == 1
    finally:
        await client.close()


def test_a_missing_binary_fails_and_says_how_to_build_it(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("FLEET_FERRETDB_BIN", str(tmp_path / "no-ferretdb"))
    with pytest.raises(pytest.fail.Exception, match=r"make test.*tools/ferretdb/build\.sh"):
        require_ferretdb_binary()

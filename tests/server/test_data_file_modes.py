"""The embedded store's files hold every user, token digest and password hash (issue 12,
finding 12c): after a run they are readable by their owner only (0600), in a folder made
owner-only (0700), whatever the umask."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.settings import Settings
from server.storage import journal as journal_module
from tests.factories import ADMIN_TOKEN, make_user, make_vehicle


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture
def loose_umask() -> Iterator[None]:
    """The most permissive common umask: what the files get is the server's doing."""
    former = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(former)


def settings_at(snapshot: Path) -> Settings:
    return Settings(  # type: ignore[call-arg]
        _env_file=None,
        snapshot_path=snapshot,
        admin_token=ADMIN_TOKEN,
        snapshot_interval_s=0.05,
    )


async def run_once(settings: Settings) -> None:
    app = create_app(settings)
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
            await make_vehicle(c)
            await make_user(c, "operator", password="correct horse battery")
            await app.state.services.store.flush()


@pytest.mark.usefixtures("loose_umask")
async def test_data_files_are_owner_only_after_a_run(tmp_path: Path) -> None:
    data = tmp_path / "data"  # not there yet: the server makes it
    snapshot = data / "fleet-store.snapshot"
    await run_once(settings_at(snapshot))
    journal = data / "fleet-store.snapshot.journal"
    assert oct(mode(data)) == oct(0o700)
    assert oct(mode(snapshot)) == oct(0o600)
    assert oct(mode(journal)) == oct(0o600)
    assert not (data / "fleet-store.snapshot.tmp").exists()
    assert sorted(p.name for p in data.iterdir()) == [snapshot.name, journal.name]

    # An entry that cannot be replayed is set aside in `.rejected`: owner-only too.
    bad = journal_module.Journal.encode(
        "update", "users", flt={"_id": "admin"}, update={"$inc": {}}
    )
    with journal.open("ab") as fh:
        fh.write(bad)
    await run_once(settings_at(snapshot))
    rejected = data / "fleet-store.snapshot.rejected"
    assert rejected.stat().st_size > 0
    for path in (snapshot, journal, rejected):
        assert oct(mode(path)) == oct(0o600), path


@pytest.mark.usefixtures("loose_umask")
async def test_files_a_former_version_left_readable_are_made_owner_only(tmp_path: Path) -> None:
    snapshot = tmp_path / "store.snapshot"
    await run_once(settings_at(snapshot))
    journal = tmp_path / "store.snapshot.journal"
    for path in (snapshot, journal):
        path.chmod(0o644)  # as the former version made them
    shared = mode(tmp_path)
    await run_once(settings_at(snapshot))
    assert oct(mode(snapshot)) == oct(0o600)
    assert oct(mode(journal)) == oct(0o600)
    assert mode(tmp_path) == shared  # a folder that was there is left alone

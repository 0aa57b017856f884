"""Store servers for the tests: FerretDB (MongoDB's wire protocol over SQLite) and the
``store_backend`` parametrisation that runs a module on the embedded store and on it.

FerretDB is built from the Go module proxy by ``tools/ferretdb/build.sh`` (``make test``
does it once, into ``.cache/``). ``FLEET_FERRETDB_BIN`` names another binary. With
``FLEET_TEST_MONGO_URL`` set, the ``mongo_url`` fixture (and so the ``ferretdb`` backend)
uses that server instead: the same suite runs against any MongoDB. A missing binary
fails the tests that need it, with what to run; they are never skipped.

Fixtures (registered by ``tests/conftest.py``):

- ``ferretdb`` (session): one running :class:`FerretDB` shared by the session.
- ``make_ferretdb`` (function): ``make_ferretdb() -> FerretDB``, a private server (fresh
  folder, own port) that the test may ``stop()``, ``kill()`` and ``start()``; stopped after.
- ``mongo_url`` (function): a :class:`MongoTarget` ``(url, db_name)``, a database name of
  its own for the test on the shared server; the database is dropped after.
- ``store_backend`` (function, params ``embedded`` / ``ferretdb``): a module opts in with
  ``pytestmark = pytest.mark.usefixtures("store_backend")``; ``make_settings`` then builds
  settings for the backend (``ferretdb``: ``mongo_url`` and ``db_name`` of ``mongo_url``).
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import socket
import subprocess
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import pytest
from pymongo import MongoClient
from pymongo.errors import PyMongoError

ROOT = Path(__file__).resolve().parent.parent
TOOL_GO_MOD = ROOT / "tools" / "ferretdb" / "go.mod"
BACKENDS = ("embedded", "ferretdb")
BACKEND_PROPERTY = "store_backend"


def ferretdb_version() -> str:
    """The FerretDB version pinned in ``tools/ferretdb/go.mod``."""
    found = re.search(r"^\s*github\.com/FerretDB/FerretDB\s+(v\S+)", TOOL_GO_MOD.read_text(), re.M)
    if found is None:
        raise RuntimeError(f"no github.com/FerretDB/FerretDB version in {TOOL_GO_MOD}")
    return found.group(1)


def ferretdb_binary() -> Path:
    """``FLEET_FERRETDB_BIN``, else where ``tools/ferretdb/build.sh`` puts the binary."""
    given = os.environ.get("FLEET_FERRETDB_BIN")
    if given:
        return Path(given)
    return ROOT / ".cache" / "ferretdb" / ferretdb_version() / "bin" / "ferretdb"


def require_ferretdb_binary() -> Path:
    """The binary, or the test fails (never skips) saying how to build it."""
    binary = ferretdb_binary()
    if not (binary.is_file() and os.access(binary, os.X_OK)):
        pytest.fail(
            f"FerretDB binary not found at {binary}. Run `make test` (it builds it once) or "
            "`tools/ferretdb/build.sh` (needs Go >= 1.24 and the Go module proxy); or set "
            "FLEET_FERRETDB_BIN to a built binary, or FLEET_TEST_MONGO_URL to a MongoDB server.",
            pytrace=False,
        )
    return binary


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class FerretDB:
    """One FerretDB process on a loopback port, keeping its data (SQLite files) in
    ``directory``; it can be stopped, killed and started again on the same port and data.

    ``start``/``stop``/``kill`` block (at most their timeouts); from a test whose event
    loop also runs the server under test, call them with ``asyncio.to_thread``.
    """

    def __init__(self, binary: Path, directory: Path, port: int | None = None) -> None:
        self.binary = binary
        self.directory = directory
        self.port = port or free_port()
        self.data_dir = directory / "data"
        self.state_dir = directory / "state"
        self.log_path = directory / "ferretdb.log"
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"mongodb://127.0.0.1:{self.port}/?directConnection=true"

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def log_tail(self, lines: int = 20) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except FileNotFoundError:
            return "(no log)"

    def start(self, timeout_s: float = 30.0) -> None:
        """Start the process and return once it answers ``ping``."""
        if self.running:
            raise RuntimeError(f"FerretDB on port {self.port} is already running")
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.state_dir.mkdir(parents=True, exist_ok=True)
        with self.log_path.open("ab") as log:
            self.process = subprocess.Popen(
                [
                    str(self.binary),
                    "--handler=sqlite",
                    f"--sqlite-url=file:{self.data_dir}/",
                    f"--listen-addr=127.0.0.1:{self.port}",
                    f"--state-dir={self.state_dir}",
                    "--debug-addr=-",
                    "--telemetry=disable",
                    "--log-level=warn",
                ],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
            )
        deadline = time.monotonic() + timeout_s
        client: MongoClient[dict[str, Any]] = MongoClient(
            self.url, serverSelectionTimeoutMS=250, connectTimeoutMS=250, socketTimeoutMS=2000
        )
        with client:
            while True:
                try:
                    client.admin.command("ping")
                    return
                except PyMongoError as error:
                    exited = self.process.poll()
                    if exited is not None or time.monotonic() > deadline:
                        self.kill()
                        why = f"exited with {exited}" if exited is not None else f"{error}"
                        raise RuntimeError(
                            f"FerretDB did not answer ping on port {self.port} within "
                            f"{timeout_s} s ({why}); its log:\n{self.log_tail()}"
                        ) from None

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop it cleanly (SIGTERM), killing it if it outlives ``timeout_s``."""
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=timeout_s)
        self.process = None

    def kill(self) -> None:
        """Kill it at once (SIGKILL): no goodbye to connected clients."""
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)
        self.process = None


class MongoTarget(NamedTuple):
    """A MongoDB server's URL and a database name of the test's own."""

    url: str
    db_name: str


_db_numbers = itertools.count(1)


def unique_db_name() -> str:
    return f"fleet_t{os.getpid()}_{next(_db_numbers)}_{uuid.uuid4().hex[:6]}"


def drop_database(target: MongoTarget) -> None:
    client: MongoClient[dict[str, Any]] = MongoClient(target.url, serverSelectionTimeoutMS=5000)
    with client:
        client.drop_database(target.db_name)


@pytest.fixture(scope="session")
def ferretdb(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FerretDB]:
    """One FerretDB for the session, on a fresh folder and a free port."""
    server = FerretDB(require_ferretdb_binary(), tmp_path_factory.mktemp("ferretdb"))
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def make_ferretdb(tmp_path: Path) -> Iterator[Callable[[], FerretDB]]:
    """``make_ferretdb()``: a started FerretDB of the test's own (stopped afterwards)."""
    made: list[FerretDB] = []

    def make() -> FerretDB:
        server = FerretDB(require_ferretdb_binary(), tmp_path / f"ferretdb{len(made)}")
        made.append(server)
        server.start()
        return server

    try:
        yield make
    finally:
        for server in made:
            server.stop()


@pytest.fixture
def mongo_url(request: pytest.FixtureRequest) -> Iterator[MongoTarget]:
    """A server URL and a database of this test's own, dropped afterwards:
    ``FLEET_TEST_MONGO_URL`` when set, else the session's FerretDB."""
    given = os.environ.get("FLEET_TEST_MONGO_URL")
    server: FerretDB | None = None
    if given:
        target = MongoTarget(given, unique_db_name())
    else:
        server = request.getfixturevalue("ferretdb")
        target = MongoTarget(server.url, unique_db_name())
    yield target
    if server is not None and not server.running:
        # It died under this test: say so here, and bring it back for the tests after.
        exit_code = server.process.returncode if server.process is not None else None
        log = server.log_tail()
        server.process = None
        server.start()
        pytest.fail(f"FerretDB exited during this test (code {exit_code}); its log:\n{log}")
    drop_database(target)


class StoreBackend(NamedTuple):
    """A backend's name and the settings that select it (merged by ``make_settings``)."""

    name: str
    settings: dict[str, Any]


@pytest.fixture(params=BACKENDS)
def store_backend(request: pytest.FixtureRequest) -> StoreBackend:
    """The store a test runs on; opt a module in with
    ``pytestmark = pytest.mark.usefixtures("store_backend")``."""
    name: str = request.param
    if name == "embedded":
        return StoreBackend(name, {})
    target: MongoTarget = request.getfixturevalue("mongo_url")
    return StoreBackend(name, {"mongo_url": target.url, "db_name": target.db_name})


# Hooks (this module is a plugin of tests/conftest.py).


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tag each item run on a backend, so its reports say which (for the summary)."""
    for item in items:
        callspec = getattr(item, "callspec", None)
        if callspec is not None and BACKEND_PROPERTY in callspec.params:
            item.user_properties.append((BACKEND_PROPERTY, callspec.params[BACKEND_PROPERTY]))


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """``storage backends: embedded 120 passed; ferretdb 118 passed, 2 failed``."""
    counts: dict[str, Counter[str]] = {}
    for outcome in ("passed", "failed", "error", "skipped", "xfailed", "xpassed"):
        for report in terminalreporter.stats.get(outcome, []):
            backend = dict(getattr(report, "user_properties", ())).get(BACKEND_PROPERTY)
            if backend is not None:
                counts.setdefault(backend, Counter())[outcome] += 1
    if not counts:
        return
    order = {name: rank for rank, name in enumerate(BACKENDS)}
    parts = []
    for backend in sorted(counts, key=lambda b: (order.get(b, len(order)), b)):
        shown = ", ".join(f"{n} {outcome}" for outcome, n in counts[backend].items())
        parts.append(f"{backend} {shown}")
    terminalreporter.write_line("storage backends: " + "; ".join(parts))

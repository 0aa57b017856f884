"""``fleetctl`` refuses bad arguments itself: one line on stderr, exit 2, and nothing sent.

The server named here listens nowhere: a command that sent a request would end with exit 3
(cannot reach) instead.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import Result

from remote_client.cli import app
from tests.factories import ADMIN_TOKEN
from tests.fleetctl_run import runner
from tests.live import free_port


def fleetctl(*args: str) -> Result:
    """``fleetctl ARGS`` with ``FLEET_SERVER`` a port nobody listens on."""
    env = {"FLEET_SERVER": f"http://127.0.0.1:{free_port()}", "FLEET_TOKEN": ADMIN_TOKEN}
    return runner.invoke(app, list(args), env=env)


def assert_refused(result: Result, named: str) -> None:
    """Exit 2, one line on stderr naming ``named``, nothing on stdout."""
    assert result.exit_code == 2, result.output
    assert result.stderr.count("\n") == 1 and named in result.stderr, result.stderr
    assert result.stdout == ""


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("goto", "Alpha", "nan", "15"), "LAT"),
        (("goto", "Alpha", "43.94", "inf"), "LON"),
        (("goto", "Alpha", "43.94", "-inf"), "LON"),
        (("goto", "Alpha", "43.94", "15", "--speed", "NaN"), "--speed"),
        (("station", "Alpha", "--lat", "inf", "--lon", "15"), "--lat"),
        (("station", "Alpha", "--radius", "nan"), "--radius"),
        (("path", "Alpha", "43.94,15", "nan,15"), "'nan,15'"),
        (("path", "Alpha", "43.94,15", "--speed", "infinity"), "--speed"),
        (("watch", "--seconds", "inf"), "--seconds"),
        (("alive", "--seconds", "inf"), "--seconds"),
        (("zones", "add", "Reef", "reef.geojson", "--clearance", "nan"), "--clearance"),
        (("failsafe", "set", "Alpha", "stop", "--after", "inf"), "--after"),
        (("failsafe", "set", "Alpha", "stop", "--low-battery", "nan"), "--low-battery"),
        (("failsafe", "set", "Alpha", "return_home", "--home", "43.94,-inf"), "--home"),
    ],
)
def test_a_float_that_is_not_finite_is_refused_before_anything_is_sent(
    args: tuple[str, ...], named: str
) -> None:
    assert_refused(fleetctl(*args), named)


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("goto", "Alpha", "91", "15"), "LAT is a latitude, from -90 to 90"),
        (("goto", "Alpha", "--", "-90.5", "15"), "LAT is a latitude"),
        (("goto", "Alpha", "43.94", "180.01"), "LON is a longitude, from -180 to 180"),
        (("station", "Alpha", "--lat", "43", "--lon", "-181"), "--lon is a longitude"),
        (("path", "Alpha", "43.94,15", "95,15"), "'95,15'"),
        (("failsafe", "set", "Alpha", "return_home", "--home", "43.94,200"), "--home"),
        (("events", "--kind", "bogus"), "--kind is one of instance, presence, command"),
        (("goto", "Alpha", "43.94", "15", "--speed", "0"), "--speed is above 0"),
        (("goto", "Alpha", "43.94", "15", "--speed", "51"), "--speed is at most 50"),
        (("goto", "Alpha", "43.94", "15", "--ttl", "0"), "--ttl is at least 1"),
        (("goto", "Alpha", "1", "2", "--ttl", "99999"), "--ttl is at most 3600"),
        (("station", "Alpha", "--radius", "-1"), "--radius is above 0"),
        (("export", "Alpha", "--since", "10m", "--until", "20m"), "the window is empty"),
        (("goto", "43.94", "15"), "give a vehicle (or more), then LAT and LON"),
        (("goto", "Alpha", "Bravo", "43.94", "east"), "LON is a number, not 'east'"),
        (("path", "43.94,15", "43.95,15"), "give a vehicle (or more) before the waypoints"),
        (("path", "Alpha", "Bravo"), "then the waypoints as LAT,LON pairs"),
        (("path", "Alpha", "43.94", "15"), "not a LAT,LON pair"),
        (("watch", "Bad/Topic"), "not a topic: 'Bad/Topic'"),
        (("watch", "fleet", "user/a//b"), "no empty segment"),
    ],
)
def test_a_position_out_of_range_or_an_unknown_kind_is_refused_before_anything_is_sent(
    args: tuple[str, ...], named: str
) -> None:
    assert_refused(fleetctl(*args), named)


@pytest.mark.parametrize(
    ("server", "said"),
    [
        ("127.0.0.1:8741", "FLEET_SERVER is a URL with its scheme: give http://127.0.0.1:8741"),
        ("localhost:8741", "give http://localhost:8741"),
        ("ftp://fleet.example.org", "FLEET_SERVER is an http:// or https:// URL"),
        ("http://", "FLEET_SERVER is an http:// or https:// URL"),
        ("http://127.0.0.1:8741/api", "without /api: give http://127.0.0.1:8741"),
        ("https://fleet.example.org/api/", "without /api: give https://fleet.example.org"),
        (
            "https://ops:s3cret@fleet.example.org/",
            "without a user name or password (the token is what signs in, and the URL is "
            "shown in logs): give https://fleet.example.org/, not 'https://***@fleet.example.org/'",
        ),
    ],
)
@pytest.mark.parametrize("args", [("vehicles",), ("watch", "--seconds", "1"), ("alive",)])
def test_a_server_address_that_is_no_servers_root_is_refused_before_anything_is_sent(
    server: str, said: str, args: tuple[str, ...]
) -> None:
    """Exit 2, a bad argument (it was exit 3, the server out of reach, or a 404 from a
    server asked for /api/api/vehicles)."""
    refused = runner.invoke(
        app, list(args), env={"FLEET_SERVER": server, "FLEET_TOKEN": ADMIN_TOKEN}
    )
    assert_refused(refused, said)


def test_server_and_token_may_come_before_the_command() -> None:
    """``fleetctl --server URL vehicles`` was "No such option: --server": given before the
    command they stand for FLEET_SERVER and FLEET_TOKEN (env restored after each run)."""
    env = {"FLEET_SERVER": None, "FLEET_TOKEN": None}
    bad = runner.invoke(app, ["--server", "127.0.0.1:8741", "vehicles"], env=env)
    assert_refused(bad, "--server is a URL with its scheme: give http://127.0.0.1:8741")
    args = ["--server", "http://127.0.0.1:9", "--token", ADMIN_TOKEN, "vehicles"]
    away = runner.invoke(app, args, env=env)
    assert away.exit_code == 3 and "cannot reach http://127.0.0.1:9" in away.stderr, away.output
    no_token = runner.invoke(app, ["--server", "http://127.0.0.1:9", "vehicles"], env=env)
    assert no_token.exit_code == 2 and "FLEET_TOKEN" in no_token.output, no_token.output


def test_a_server_given_as_an_option_is_named_so() -> None:
    env = {"FLEET_SERVER": "http://127.0.0.1:8741", "FLEET_TOKEN": ADMIN_TOKEN}
    given = runner.invoke(app, ["users", "--server", "127.0.0.1:8741"], env=env)
    assert_refused(given, "--server is a URL with its scheme")


ID_RULE = "is 1 to 64 characters of a-z, 0-9, - and _, the first a letter or a digit"


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("users", "add", "Bad Name"), f"USERNAME {ID_RULE}, not 'Bad Name'"),
        (("users", "add", "x" * 65, "--role", "viewer"), f"USERNAME {ID_RULE}"),
        (("users", "set", "Ana", "--role", "viewer"), f"USERNAME {ID_RULE}, not 'Ana'"),
        (("users", "disable", "_ana"), f"USERNAME {ID_RULE}, not '_ana'"),
        (("users", "token", "ana smith"), f"USERNAME {ID_RULE}"),
        (("vehicles", "add", "Not An Id"), f"VEHICLE_ID {ID_RULE}, not 'Not An Id'"),
        (("vehicles", "add", "i-0123456789abcdef"), "shaped like an id the server gives"),
        (("gateways", "add", "GW 1", "-v", "usv-1"), f"GATEWAY_ID {ID_RULE}"),
        (("gateways", "revoke", "gw.1"), f"GATEWAY_ID {ID_RULE}"),
        (("grant", "Alpha", "Ana Smith"), f"USER {ID_RULE}, not 'Ana Smith'"),
        (("deny", "Alpha", "ana!"), f"USER {ID_RULE}"),
    ],
)
def test_a_name_or_id_the_server_would_refuse_is_refused_in_words_before_anything_is_sent(
    args: tuple[str, ...], named: str
) -> None:
    """As the protocol's models take it (``fleet_protocol``: a username, a vehicle's and a
    gateway's id), said in words: it was sent, and refused with the pattern itself."""
    refused = fleetctl(*args)
    assert_refused(refused, named)
    assert "^[a-z0-9]" not in refused.stderr


TRACK_ENDINGS = ".json, .geojson, .gpx, .csv, .png"


@pytest.mark.parametrize(
    ("args", "endings"),
    [
        (("track", "Alpha", "--since", "10m", "-o", "alpha.kml"), TRACK_ENDINGS),
        (("track", "Alpha", "-o", "alpha"), TRACK_ENDINGS),
        (("export", "Alpha", "-o", "alpha.json"), ".jsonl, .csv"),
        (("export", "Alpha", "-o", "alpha.txt"), ".jsonl, .csv"),
    ],
)
def test_a_file_whose_ending_names_no_format_is_refused_before_anything_is_sent(
    args: tuple[str, ...], endings: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert_refused(fleetctl(*args), endings)
    assert list(tmp_path.iterdir()) == []  # no file written, not even an empty one


def test_format_names_the_format_whatever_the_file_is_called(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    chosen = fleetctl("track", "Alpha", "--format", "gpx", "-o", "alpha.kml")
    assert chosen.exit_code == 3 and "cannot reach" in chosen.stderr  # past the arguments


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("export", "Alpha", "-o", "no-such-folder/x.csv"), "no-such-folder"),
        (("track", "Alpha", "-o", "no-such-folder/x.gpx"), "no-such-folder"),
        (("track", "Alpha", "-o", "no-such-folder/x.png"), "no-such-folder"),
        (("sync", "Alpha", "--db", "no-such-folder/x.sqlite"), "no-such-folder"),
    ],
)
def test_a_file_in_a_folder_that_is_not_there_is_refused_before_anything_is_sent(
    args: tuple[str, ...], named: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert_refused(fleetctl(*args), named)

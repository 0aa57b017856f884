"""``fleet-server``'s command line: a bad setting is refused before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from server.cli import app


def test_each_bad_setting_is_one_line_naming_its_variable_and_what_it_takes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # no .env but this test's
    env = {"FLEET_TOKEN_TTL_S": "2", "FLEET_LOG_FORMAT": "xml", "FLEET_ADMIN_TOKEN": "secret-x"}
    refused = CliRunner().invoke(app, ["--port", "8011"], env=env)
    assert refused.exit_code == 2, refused.output
    assert sorted(refused.stderr.splitlines()) == [
        "FLEET_ADMIN_TOKEN: an admin token has at least 16 characters "
        "(python3 -c 'import secrets; print(secrets.token_urlsafe(32))' makes one)",
        "FLEET_LOG_FORMAT: input should be 'text' or 'json'",
        "FLEET_TOKEN_TTL_S: input should be greater than or equal to 60",
    ]
    assert "secret-x" not in refused.output
    assert refused.stdout == ""


def test_a_bad_option_is_named_as_the_option_and_a_bad_line_of_dot_env_as_its_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / ".env").write_text("FLEET_STALE_AFTER_S=0\n")
    refused = CliRunner().invoke(app, ["--port", "70000"])
    assert refused.exit_code == 2, refused.output
    assert sorted(refused.stderr.splitlines()) == [
        "--port: input should be less than or equal to 65535",
        "FLEET_STALE_AFTER_S: input should be greater than 0",
    ]


def test_presence_times_out_of_order_are_refused_naming_both(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FLEET_STALE_AFTER_S", "20")  # stale after offline: cannot hold
    monkeypatch.setenv("FLEET_OFFLINE_AFTER_S", "10")
    refused = CliRunner().invoke(app, [])
    assert refused.exit_code == 2, refused.output
    assert refused.stderr.splitlines() == [
        "FLEET_OFFLINE_AFTER_S: a vehicle goes offline no sooner than it goes stale "
        "(FLEET_STALE_AFTER_S is 20); give at least that"
    ]
    monkeypatch.setenv("FLEET_HEARTBEAT_INTERVAL_S", "30")
    monkeypatch.setenv("FLEET_OFFLINE_AFTER_S", "60")
    beat = CliRunner().invoke(app, [])
    assert beat.exit_code == 2 and "FLEET_STALE_AFTER_S: a vehicle goes stale no sooner" in (
        beat.stderr
    )

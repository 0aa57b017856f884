"""``fleet-agent`` settings: options over FLEET_AGENT_* over TOML, and clear refusals."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import BaseModel
from typer.testing import CliRunner

from vehicle_client.cli import app
from vehicle_client.config import AgentSettings, GatewaySettings, load
from vehicle_client.errors import FatalError
from vehicle_client.outbox import Outbox

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "gateway.toml"
runner = CliRunner()


@pytest.fixture(autouse=True)
def _clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for key in list(os.environ):
        if key.startswith("FLEET_AGENT_"):
            monkeypatch.delenv(key)


def test_options_win_over_env_which_wins_over_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "agent.toml"
    config.write_text('vehicle_id = "usv-file"\nrate_hz = 2.0\ntime_scale = 3.0\n')
    monkeypatch.setenv("FLEET_AGENT_RATE_HZ", "5")
    settings = load(AgentSettings, config, time_scale=10.0, start=None)
    assert settings.vehicle_id == "usv-file"
    assert settings.rate_hz == 5.0
    assert settings.time_scale == 10.0


def test_the_token_never_shows_in_the_settings_repr(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLEET_AGENT_TOKEN", "very-secret-token")
    settings = load(AgentSettings, None, vehicle_id="usv-1")
    assert settings.token.get_secret_value() == "very-secret-token"
    assert "very-secret-token" not in repr(settings)


def test_the_example_gateway_file_loads() -> None:
    settings = load(GatewaySettings, EXAMPLE)
    assert [v.vehicle_id for v in settings.vehicles] == ["usv-1", "usv-2", "usv-3"]
    assert settings.vehicles[2].max_speed_mps == 0.8


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--vehicle-id", "usv-1", "--start", "95,1"], "not a position"),
        (["run", "--vehicle-id", "USV 1"], "vehicle_id"),
        (["run", "--vehicle-id", "usv-1", "--rate-hz", "0"], "rate_hz"),
        (["run", "--vehicle-id", "usv-1", "--server", "fleet:80", "--token", "t"], "URL"),
        (["run", "--vehicle-id", "usv-1", "--server", "http://x"], "no token"),
        (["run"], "no vehicle"),
        (["run", "--config", "/nonexistent/agent.toml"], "not found"),
        (["run", "--config", "/tmp"], "/tmp is a directory"),
        # Every call answered 404 (/api/api/...): retried for ever, now refused at start.
        (
            ["run", "--vehicle-id", "usv-1", "--server", "http://127.0.0.1:9/api"],
            "without /api: give http://127.0.0.1:9",
        ),
        (["gateway", "--config", "/nonexistent/gateway.toml"], "not found"),
    ],
)
def test_bad_configuration_exits_2_with_a_clear_message(args: list[str], message: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert "fleet-agent: error:" in result.output
    assert message in result.output


def test_a_server_url_with_a_password_is_refused_without_showing_the_password() -> None:
    """A user name and password in --server were sent to no one (the token signs in) and
    shown in the agent's logs: refused at start, the URL shown without them."""
    given = ["run", "--vehicle-id", "usv-1", "--token", "t"]
    result = runner.invoke(app, [*given, "--server", "https://ana:s3cret@fleet.example.org:8443"])
    assert result.exit_code == 2, result.output
    assert "without a user name or password" in result.output
    assert "give https://fleet.example.org:8443," in result.output
    assert "s3cret" not in result.output and "ana" not in result.output


def _float_settings(cls: type[BaseModel]) -> list[str]:
    return [name for name, f in cls.model_fields.items() if f.annotation in (float, float | None)]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_a_float_setting_that_is_not_finite_is_said_to_need_a_finite_number(
    value: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``--rate-hz nan`` was refused as "less than or equal to 100", an infinite one
    likewise: every float setting of the agent and the gateway, from the environment or
    a file, a simulator's ``start`` and ``current`` among them, says a finite number."""
    floats = _float_settings(AgentSettings)
    assert {"rate_hz", "max_speed_mps", "time_scale", "poll_wait_s"} <= set(floats)
    for name in floats:
        monkeypatch.setenv(f"FLEET_AGENT_{name.upper()}", value)
        result = runner.invoke(app, ["run", "--vehicle-id", "usv-1", "--token", "t"])
        assert result.exit_code == 2, result.output
        assert f"{name}: Input should be a finite number" in result.output
        monkeypatch.delenv(f"FLEET_AGENT_{name.upper()}")
    for pair in ("start", "current"):
        result = runner.invoke(app, ["run", "--vehicle-id", "usv-1", f"--{pair}", f"0,{value}"])
        assert result.exit_code == 2, result.output
        assert f"{pair} must be two finite numbers" in result.output

    toml = {"nan": "nan", "inf": "inf", "-inf": "-inf"}[value]
    for name in _float_settings(GatewaySettings):
        config = tmp_path / f"{name}.toml"
        config.write_text(f'token = "t"\n{name} = {toml}\n[[vehicles]]\nvehicle_id = "a"\n')
        result = runner.invoke(app, ["gateway", "--config", str(config)])
        assert result.exit_code == 2, result.output
        assert f"{name}: Input should be a finite number" in result.output
    config = tmp_path / "vehicle.toml"
    config.write_text(f'token = "t"\n[[vehicles]]\nvehicle_id = "a"\nmax_speed_mps = {toml}\n')
    result = runner.invoke(app, ["gateway", "--config", str(config)])
    assert result.exit_code == 2, result.output
    assert "vehicles.0.max_speed_mps: Input should be a finite number" in result.output


def test_a_gateway_with_a_vehicle_twice_is_refused(tmp_path: Path) -> None:
    config = tmp_path / "gw.toml"
    config.write_text(
        'token = "t"\n[[vehicles]]\nvehicle_id = "a"\n[[vehicles]]\nvehicle_id = "a"\n'
    )
    result = runner.invoke(app, ["gateway", "--config", str(config)])
    assert result.exit_code == 2
    assert "appears twice" in result.output


def test_a_gateway_without_vehicles_is_refused(tmp_path: Path) -> None:
    config = tmp_path / "gw.toml"
    config.write_text('server = "http://127.0.0.1:1"\n')
    with pytest.raises(FatalError, match="vehicles"):
        load(GatewaySettings, config)


def test_a_key_of_the_config_file_that_is_no_setting_is_refused(tmp_path: Path) -> None:
    """A typo (``outbx``) left the default outbox in force, unsaid."""
    config = tmp_path / "agent.toml"
    config.write_text('vehicle_id = "usv-1"\ntoken = "t"\noutbx = "x.db"\n')
    result = runner.invoke(app, ["run", "--config", str(config)])
    assert result.exit_code == 2, result.output
    assert "no such setting: outbx (did you mean outbox?)" in result.output
    gateway = tmp_path / "gw.toml"
    gateway.write_text('token = "t"\n[[vehicles]]\nvehicle_id = "a"\nstrat = "43.9,15.4"\n')
    result = runner.invoke(app, ["gateway", "--config", str(gateway)])
    assert result.exit_code == 2, result.output
    assert "vehicles.0.strat (did you mean start?)" in result.output


def test_an_outbox_of_another_vehicle_is_refused(tmp_path: Path) -> None:
    """Two agents in one folder shared ./fleet-agent-outbox.db and sent each other's
    positions as their own: an outbox is its first vehicle's."""
    path = tmp_path / "fleet-agent-outbox.db"
    Outbox(path, vehicle_id="usv-7").close()
    args = ["run", "--vehicle-id", "usv-8", "--token", "t", "--server", "http://127.0.0.1:9"]
    result = runner.invoke(app, [*args, "--outbox", str(path)])
    assert result.exit_code == 2, result.output
    assert f"the outbox {path} holds vehicle usv-7's samples" in " ".join(result.output.split())
    Outbox(path, vehicle_id="usv-7").close()  # its own vehicle opens it again


def test_an_outbox_another_agent_has_open_is_refused_until_it_lets_go(tmp_path: Path) -> None:
    """Two agents of one vehicle on one outbox numbered their samples alike and deleted
    each other's: the second is refused at start, naming the first's process."""
    import os

    path = tmp_path / "usv-7.db"
    first = Outbox(path, vehicle_id="usv-7")  # an agent of usv-7 running
    args = ["run", "--vehicle-id", "usv-7", "--token", "t", "--server", "http://127.0.0.1:9"]
    result = runner.invoke(app, [*args, "--outbox", str(path)])
    assert result.exit_code == 2, result.output
    said = " ".join(result.output.split())
    assert f"the outbox {path} is in use by process {os.getpid()}: stop that agent" in said
    first.append({"ts": "2026-01-01T00:00:00Z", "lat": 43.9, "lon": 15.4})
    first.close()
    again = Outbox(path, vehicle_id="usv-7")  # let go of: its vehicle opens it again
    assert [s["seq"] for s in again.batch()] == [1]
    again.close()


def test_an_outbox_that_cannot_be_opened_is_said_in_a_line_not_a_traceback(
    tmp_path: Path,
) -> None:
    """A folder given for the outbox (or a place the agent may not write) ended the agent
    with a traceback and exit 1: no sample could be kept, so it does not start, said."""
    args = ["run", "--vehicle-id", "usv-8", "--token", "t", "--server", "http://127.0.0.1:9"]
    result = runner.invoke(app, [*args, "--outbox", str(tmp_path)])
    assert result.exit_code == 2, result.output
    said = " ".join(result.output.split())
    assert f"fleet-agent: error: the outbox {tmp_path} cannot be opened: Is a directory" in said
    assert "Traceback" not in result.output


def test_a_log_level_that_is_none_is_refused_with_the_rest_of_the_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--log-level LOUD`` was logging's ValueError, a traceback and exit 1, once every
    other setting had passed; it is a bad setting like the others now (exit 2, a line)."""
    assert load(AgentSettings, None, log_level="debug").log_level == "debug"
    assert load(AgentSettings, None, log_level="WARN").log_level == "WARN"
    said = "log_level: 'LOUD' is no log level: give DEBUG, INFO, WARNING, ERROR or CRITICAL"
    with pytest.raises(FatalError, match=said):
        load(AgentSettings, None, vehicle_id="usv-1", log_level="LOUD")
    config = tmp_path / "gateway.toml"
    config.write_text('log_level = "verbose"\n' + EXAMPLE.read_text())
    with pytest.raises(FatalError, match="log_level: 'verbose' is no log level"):
        load(GatewaySettings, config)
    monkeypatch.setenv("FLEET_AGENT_LOG_LEVEL", "loud")
    with pytest.raises(FatalError, match="log_level: 'loud' is no log level"):
        load(AgentSettings, None, vehicle_id="usv-1")

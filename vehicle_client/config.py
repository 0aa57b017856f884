"""The agent's settings: command-line options, then ``FLEET_AGENT_*`` variables, then a TOML file.

``fleet-agent run`` reads ``AgentSettings``: a flat TOML file
(``server = "..."``, ``vehicle_id = "..."``, ...) given with ``--config``.
``fleet-agent gateway`` reads ``GatewaySettings``: the shared link at the top
of the file and one ``[[vehicles]]`` table per vehicle (see
``examples/gateway.toml``).
"""

from __future__ import annotations

import difflib
import logging
import math
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, SecretStr, ValidationError, field_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from fleet_protocol.common import ID_PATTERN
from fleet_protocol.errors import error_text
from fleet_protocol.links import MAX_BINARY_FRAME_BYTES, server_root_problem
from vehicle_client.errors import FatalError
from vehicle_client.gateway.uplink import DEFAULT_MEDIA_UP_PER_S, DEFAULT_PUBLISH_UP_PER_S
from vehicle_client.outbox import DEFAULT_MAX_SAMPLES
from vehicle_client.sim.dynamics import Current


def parse_pair(text: str, what: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"{what} must be two numbers separated by a comma, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"{what} must be two finite numbers, got {text!r}")
    return a, b


class VehicleOptions(BaseModel):
    """What differs per vehicle (one in ``run``, several in a gateway)."""

    #: No setting is NaN or infinite: "a finite number", before any range is checked.
    model_config = ConfigDict(allow_inf_nan=False)

    vehicle_id: str = Field(pattern=ID_PATTERN)
    name: str = ""
    adapter: Literal["sim", "ros"] = "sim"
    #: Simulator start position, "LAT,LON" (default: off Biograd na Moru).
    start: str = "43.94,15.44"
    #: Simulator water current, "SPEED_MPS,TOWARDS_DEG".
    current: str = "0.0,0"
    max_speed_mps: float = Field(default=0.5, gt=0, le=50)
    #: The ROS bridge's local address (``--adapter ros``).
    ros_bridge: str = "127.0.0.1:9311"

    @field_validator("start")
    @classmethod
    def _start(cls, value: str) -> str:
        lat, lon = parse_pair(value, "start")
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise ValueError(f"start {value!r} is not a position (LAT,LON in degrees)")
        return value

    @field_validator("current")
    @classmethod
    def _current(cls, value: str) -> str:
        speed, _ = parse_pair(value, "current")
        if not 0 <= speed <= 5:
            raise ValueError("current speed must be within 0..5 m/s")
        return value

    @property
    def start_latlon(self) -> tuple[float, float]:
        return parse_pair(self.start, "start")

    @property
    def water_current(self) -> Current:
        return Current.from_speed(*parse_pair(self.current, "current"))


class LinkOptions(BaseSettings):
    """What the agent (or gateway) shares: the server link and the pace."""

    #: No setting is NaN or infinite: "a finite number", before any range is checked.
    model_config = SettingsConfigDict(
        env_prefix="FLEET_AGENT_", extra="ignore", allow_inf_nan=False
    )

    server: str = "http://127.0.0.1:8000"
    token: SecretStr = SecretStr("")
    rate_hz: float = Field(default=1.0, gt=0, le=100)
    time_scale: float = Field(default=1.0, gt=0, le=1000)
    poll_wait_s: float = Field(default=20.0, ge=0, le=30)
    batch_size: int = Field(default=500, ge=1, le=5000)
    max_samples: int = Field(default=DEFAULT_MAX_SAMPLES, ge=1)
    log_level: str = "INFO"
    #: ``auto``: WebSocket, HTTP long-poll while the WebSocket cannot be opened.
    transport: Literal["auto", "ws", "http"] = "auto"
    #: Seconds on HTTP (``auto``) before the WebSocket is tried again.
    retry_ws_s: float = Field(default=60.0, gt=0, le=3600)

    @field_validator("log_level")
    @classmethod
    def _log_level(cls, value: str) -> str:
        """Checked here, with the rest: logging's own ValueError came out as a traceback."""
        if value.upper() not in logging.getLevelNamesMapping():
            raise ValueError(
                f"{value!r} is no log level: give DEBUG, INFO, WARNING, ERROR or CRITICAL"
            )
        return value

    @field_validator("server")
    @classmethod
    def _server(cls, value: str) -> str:
        """The server's root URL: one ending in /api was retried for ever (every call
        answered 404); one without a scheme is refused here too, before any link."""
        if (problem := server_root_problem(value)) is not None:
            raise ValueError(problem)
        return value


class AgentSettings(LinkOptions, VehicleOptions):
    model_config = LinkOptions.model_config  # both bases say no NaN, no infinity
    vehicle_id: str = Field(default="", pattern=r"^$|" + ID_PATTERN)
    outbox: Path = Path("fleet-agent-outbox.db")


class GatewaySettings(LinkOptions):
    outbox_dir: Path = Path("fleet-gateway-outbox")
    #: The ops of every vehicle queued during one tick leave as one ``batch`` frame.
    batch_tick_s: float = Field(default=0.1, ge=0, le=5)
    #: "HOST:PORT" of the gateway's own WebSocket for its local units (none if unset).
    listen: str | None = None
    #: The largest media frame (header and bytes) a local unit may send.
    max_media_bytes: int = Field(default=MAX_BINARY_FRAME_BYTES, ge=1024, le=64 * 2**20)
    #: Media frames per second sent up to the server, all topics together (latest wins).
    media_up_per_s: float = Field(default=DEFAULT_MEDIA_UP_PER_S, gt=0, le=1000)
    #: JSON publishes per second the local units send up, all together (over it: refused
    #: to the unit, rate_limited; the vehicles' own ops keep their share of the link).
    publish_up_per_s: float = Field(default=DEFAULT_PUBLISH_UP_PER_S, gt=0, le=1000)
    vehicles: list[VehicleOptions] = Field(min_length=1, max_length=1000)


def _with_file(cls: type[BaseSettings], config: Path | None) -> type[BaseSettings]:
    class WithFile(cls):  # type: ignore[valid-type, misc]
        @classmethod
        def settings_customise_sources(
            cls,
            settings_cls: type[BaseSettings],
            init_settings: PydanticBaseSettingsSource,
            env_settings: PydanticBaseSettingsSource,
            dotenv_settings: PydanticBaseSettingsSource,
            file_secret_settings: PydanticBaseSettingsSource,
        ) -> tuple[PydanticBaseSettingsSource, ...]:
            sources = [init_settings, env_settings]
            if config is not None:
                sources.append(TomlConfigSettingsSource(settings_cls, toml_file=config))
            return tuple(sources)

    return WithFile


def _describe(exc: ValidationError) -> str:
    return "; ".join(
        f"{'.'.join(str(p) for p in e['loc']) or 'settings'}: {error_text(e)}" for e in exc.errors()
    )


def load(cls: type[BaseSettings], config: Path | None, **options: Any) -> Any:
    """Settings from options (``None`` = not given), env and ``config``; ``FatalError`` if bad."""
    if config is not None and config.is_dir():
        raise FatalError(f"config file {config} is a directory: give the TOML file in it")
    if config is not None and not config.is_file():
        raise FatalError(f"config file {config} not found")
    given = {k: v for k, v in options.items() if v is not None}
    try:
        if config is not None:
            _known_keys_only(cls, config)
        return _with_file(cls, config)(**given)
    except ValidationError as exc:
        raise FatalError(f"bad configuration: {_describe(exc)}") from None
    except (OSError, ValueError) as exc:
        raise FatalError(f"bad configuration: {exc}") from None


def _known_keys_only(cls: type[BaseSettings], config: Path) -> None:
    """``FatalError`` naming each key of the file that is no setting (a typo such as
    ``outbx`` would otherwise leave the default in force, unsaid)."""
    with config.open("rb") as f:
        data = tomllib.load(f)
    unknown = [(key, key, cls.model_fields) for key in data if key not in cls.model_fields]
    vehicles = data.get("vehicles") if "vehicles" in cls.model_fields else None
    for i, vehicle in enumerate(vehicles if isinstance(vehicles, list) else []):
        if isinstance(vehicle, dict):
            fields = VehicleOptions.model_fields
            unknown += [(f"vehicles.{i}.{k}", k, fields) for k in vehicle if k not in fields]
    if unknown:
        said = []
        for where, key, fields in unknown:
            close = difflib.get_close_matches(key, list(fields), n=1)
            said.append(f"{where}" + (f" (did you mean {close[0]}?)" if close else ""))
        raise FatalError(f"bad configuration: {config} has no such setting: {', '.join(said)}")

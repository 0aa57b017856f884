"""Server settings: the ``FLEET_*`` environment variables of API.md (and ``.env``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, ValidationError, ValidationInfo, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from fleet_protocol.links import MAX_BINARY_FRAME_BYTES, MAX_TEXT_FRAME_BYTES

DAY_S = 86400
#: The shortest ``FLEET_ADMIN_TOKEN`` taken: the admin's token opens everything.
MIN_ADMIN_TOKEN_CHARS = 16


class Settings(BaseSettings):
    model_config = SettingsConfigDict(
        env_prefix="FLEET_", env_file=".env", extra="ignore", validate_default=True
    )

    mongo_url: SecretStr | None = Field(
        default=None, description="MongoDB URL; unset: the embedded store (in process)"
    )
    db_name: str = Field(default="fleet", description="MongoDB database name")
    snapshot_path: Path = Field(
        default=Path("data/fleet-store.snapshot"),
        description="embedded store's snapshot file (written periodically and on shutdown)",
    )
    snapshot_interval_s: float = Field(
        default=5.0, gt=0, description="embedded store: seconds between snapshots"
    )
    redis_url: SecretStr | None = Field(
        default=None, description="Redis URL for fan-out between replicas; unset: one process"
    )
    host: str = Field(default="127.0.0.1", description="address to listen on")
    port: int = Field(default=8000, ge=0, le=65535, description="port to listen on")
    admin_token: SecretStr | None = Field(
        default=None,
        description=f"bootstrap admin token, at least {MIN_ADMIN_TOKEN_CHARS} characters; "
        "unset: a fresh one is printed at each start (the one printed before is revoked)",
    )
    heartbeat_interval_s: float = Field(default=1.0, gt=0, description="agents' heartbeat period")
    stale_after_s: float = Field(default=3.0, gt=0, description="presence: online -> stale")
    offline_after_s: float = Field(default=10.0, gt=0, description="presence: stale -> offline")
    ack_timeout_s: float = Field(
        default=10.0, gt=0, description="redeliver a command not acknowledged within this"
    )
    safety_radius_m: float = Field(
        default=5.0, ge=0, description="clearance a planned path keeps from other vehicles"
    )
    max_obstacles: int = Field(
        default=1000, ge=0, description="known fixed obstacles (POST /api/obstacles) at most"
    )
    plan_timeout_s: float = Field(
        default=5.0,
        gt=0,
        le=300,
        description="follow_path with plan: the time one submit may spend planning "
        "(waiting for a planner included); past it, 422",
    )
    plan_workers: int = Field(
        default=2,
        ge=1,
        le=32,
        description="paths planned at once (each in a thread of its own); a submit waits for "
        "one up to plan_timeout_s, then 429",
    )
    retention_s: float = Field(
        default=7 * DAY_S,
        gt=0,
        description="telemetry, events and finished commands older than this are dropped",
    )
    max_body_bytes: int = Field(
        default=1_048_576, ge=1024, description="largest request body accepted (else 413)"
    )
    failsafe_after_s: float = Field(
        default=30.0,
        gt=0,
        le=86_400,
        description="a vehicle's failsafe until set for it (PUT /api/vehicles/{id}/failsafe): "
        "act after this silence",
    )
    failsafe_action: Literal["none", "keep_station", "stop", "return_home"] = Field(
        default="keep_station", description="a vehicle's failsafe action until set for it"
    )
    separation_m: float = Field(
        default=10.0,
        ge=0,
        le=10_000,
        description="follow_path with plan to several vehicles: the paths keep this apart; "
        "the collision forecast warns of two vehicles coming closer (0: neither)",
    )
    forecast_s: float = Field(
        default=60.0,
        ge=0,
        le=3600,
        description="how far ahead the collision forecast projects each online vehicle's "
        "course and speed (0: no forecast)",
    )
    forecast_every_s: float = Field(
        default=1.0, gt=0, le=60, description="how often the collision forecast runs"
    )
    rules_every_s: float = Field(
        default=1.0,
        gt=0,
        le=60,
        description="how often a replica reads the zones and failsafe policies again "
        "(another replica's change is heard on the bus at once; this is when it is not)",
    )
    token_ttl_s: int = Field(
        default=12 * 3600, ge=60, description="lifetime of a token from /auth/token"
    )
    login_window_s: float = Field(
        default=300.0,
        gt=0,
        description="/auth/token: failed logins are counted over this sliding window "
        "(kept in the store, so every replica counts the same ones)",
    )
    login_failures_per_address: int = Field(
        default=10,
        ge=1,
        description="/auth/token: failed logins from one client address (IPv6: one /64) "
        "within login_window_s; past it, 429 rate_limited with Retry-After",
    )
    login_failures_per_user: int = Field(
        default=20,
        ge=1,
        description="/auth/token: failed logins for one username, from any address, "
        "within login_window_s; past it, 429 rate_limited with Retry-After",
    )
    bucket_samples: int = Field(
        default=200, ge=1, le=10_000, description="telemetry samples per stored bucket"
    )
    bucket_max_bytes: int = Field(
        default=1_048_576,
        ge=65_536,
        le=8_388_608,
        description="telemetry bytes per stored bucket at most (BSON documents end at 16 MiB)",
    )
    bucket_max_age_s: float = Field(
        default=10.0,
        gt=0,
        description="a partly filled telemetry bucket is written at most this long after its "
        "first sample (each vehicle's a little sooner, so that buckets opened together are not "
        "written together)",
    )
    persist_interval_s: float = Field(
        default=10.0,
        gt=0,
        description="how often vehicles' last contact and position are saved "
        "(several replicas: at least every stale_after_s / 3)",
    )
    long_poll_max: int = Field(default=4, ge=1, description="open long polls per vehicle")
    max_pending_requests: int = Field(
        default=50, ge=1, description="pending control requests per instance"
    )
    control_request_ttl_s: float = Field(
        default=600.0, gt=0, description="an unanswered control request is dropped after this"
    )
    command_history_limit: int = Field(
        default=50, ge=1, description="recent commands shown by get_fbmessage"
    )
    rate_limit_per_s: float = Field(
        default=200.0, gt=0, description="requests per second per token before 429"
    )
    rate_limit_burst: int = Field(default=400, ge=1, description="burst allowance per token")
    ws_queue_size: int = Field(
        default=1000, ge=10, description="frames waiting per WebSocket before the oldest drop"
    )
    ws_queue_bytes: int = Field(
        default=8 * 2**20,
        ge=65_536,
        description="bytes waiting per WebSocket before it is closed (4429: reading too slowly)",
    )
    ws_auth_wait_s: float = Field(
        default=10.0,
        gt=0,
        le=300,
        description="a socket opened without a token has this long to send its auth frame",
    )
    ws_ops_per_s: float = Field(
        default=500.0, gt=0, description="ops per second per WebSocket before rate_limited"
    )
    ws_max_topics: int = Field(
        default=256, ge=1, description="topics one unit may register, and subscribe to"
    )
    ws_max_binary_bytes: int = Field(
        default=MAX_BINARY_FRAME_BYTES, ge=1024, description="largest binary (media) frame accepted"
    )
    ws_max_text_bytes: int = Field(
        default=MAX_TEXT_FRAME_BYTES,
        ge=1024,
        description="largest JSON frame accepted on a WebSocket",
    )
    store_timeout_ms: int = Field(
        default=2000, ge=100, description="MongoDB server selection / operation timeout"
    )
    store_write_concern: str = Field(
        default="majority",
        pattern=r"^(majority|[0-9]{1,2})$",
        description="MongoDB write concern w: 'majority' or a number of members; "
        "telemetry is reported durable once a write is acknowledged with it",
    )
    store_journal: bool = Field(
        default=True, description="MongoDB write concern j: acknowledge after the journal"
    )
    store_retry_max_s: float = Field(
        default=30.0, gt=0, description="longest wait between tries to reach the store at start"
    )
    log_level: str = Field(default="info", description="log level")
    log_format: Literal["text", "json"] = Field(
        default="text",
        description="log lines: text (one readable line each) or json (one JSON object per "
        "line: time, level, logger, message, exception)",
    )
    map_tile_url: str | None = Field(
        default=None,
        max_length=2048,
        description="console: a raster tile URL ({z}/{x}/{y}) drawn under the map's offline "
        "grid; unset: the grid, zones and obstacles only (works with no internet)",
    )
    map_tile_attribution: str = Field(
        default="", max_length=512, description="console: the credit shown with map_tile_url"
    )
    web_vendor_dir: Path | None = Field(
        default=None,
        description="where `npm ci` put leaflet and swagger-ui-dist (a node_modules folder); "
        "unset: server/web/node_modules beside the code",
    )

    @field_validator("admin_token")
    @classmethod
    def _long_enough(cls, token: SecretStr | None) -> SecretStr | None:
        if token is not None and len(token.get_secret_value()) < MIN_ADMIN_TOKEN_CHARS:
            raise ValueError(
                f"an admin token has at least {MIN_ADMIN_TOKEN_CHARS} characters "
                "(python3 -c 'import secrets; print(secrets.token_urlsafe(32))' makes one)"
            )
        return token

    @field_validator("stale_after_s", "offline_after_s")
    @classmethod
    def _in_order(cls, value: float, info: ValidationInfo) -> float:
        """Presence goes online, stale, offline: each time no sooner than the one before
        (and stale no sooner than a heartbeat interval)."""
        earlier, said = _PRESENCE_ORDER[str(info.field_name)]
        before = info.data.get(earlier)
        if before is not None and value < before:
            raise ValueError(
                f"a vehicle {said} ({env_name(earlier)} is {before:g}); give at least that"
            )
        return value

    @property
    def embedded(self) -> bool:
        return self.mongo_url is None

    @property
    def contact_write_s(self) -> float:
        """How often a vehicle's last contact is written to the store.

        One replica: ``persist_interval_s``. Several (``FLEET_REDIS_URL`` set): often
        enough that another replica reading it back never takes a vehicle in contact
        for stale.
        """
        if self.redis_url is not None:
            return min(self.persist_interval_s, self.stale_after_s / 3)
        return self.persist_interval_s

    @property
    def read_ahead_s(self) -> float:
        """How long before a presence change the stored contact is read back: with several
        replicas, ``contact_write_s`` (another may be in contact with the vehicle); with
        one, nothing is newer than this replica's copy."""
        return self.contact_write_s if self.redis_url is not None else 0.0


#: Each presence time, the one it comes no sooner than, and how that reads.
_PRESENCE_ORDER = {
    "stale_after_s": ("heartbeat_interval_s", "goes stale no sooner than its heartbeat interval"),
    "offline_after_s": ("stale_after_s", "goes offline no sooner than it goes stale"),
}


def env_name(field: str) -> str:
    """The environment variable of a setting: ``token_ttl_s`` is ``FLEET_TOKEN_TTL_S``."""
    return f"{Settings.model_config.get('env_prefix', '')}{field.upper()}"


def refusals(exc: ValidationError) -> dict[str, str]:
    """What is wrong with each bad setting of ``exc``, by field name, in pydantic's words
    (``input should be greater than or equal to 60``); the values are not repeated, since
    some are secrets."""
    found: dict[str, list[str]] = {}
    for error in exc.errors():
        field = str(error["loc"][0]) if error["loc"] else "settings"
        message = str(error["msg"]).removeprefix("Value error, ")
        found.setdefault(field, []).append(message[:1].lower() + message[1:])
    return {field: "; ".join(messages) for field, messages in found.items()}

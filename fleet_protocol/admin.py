"""Administration: vehicles, gateways, users, tokens."""

from __future__ import annotations

import re
from typing import Annotated, Literal

from pydantic import AfterValidator, ConfigDict, Field, StrictBool, field_validator

from fleet_protocol.common import Identifier, Timestamp, WireModel, refuse_null
from fleet_protocol.text import Label, Text


def _once_each(ids: list[str]) -> list[str]:
    return list(dict.fromkeys(ids))


#: Vehicle ids given to a user or a gateway: each kept once, in the order first given.
VehicleIds = Annotated[list[Identifier], AfterValidator(_once_each)]

__all__ = [
    "SERVER_ACTOR",
    "CallerView",
    "CreateGateway",
    "CreateUser",
    "CreateVehicle",
    "DeadLetter",
    "DeadLetterList",
    "GatewayCreated",
    "GatewayList",
    "GatewayView",
    "LoginRequest",
    "LogoutResult",
    "PatchUser",
    "PatchVehicle",
    "Role",
    "TokenResult",
    "UserCreated",
    "UserList",
    "UserView",
    "VehicleCreated",
]

Role = Literal["viewer", "operator", "manager", "admin"]
ROLE_RANK = {"viewer": 0, "operator": 1, "manager": 2, "admin": 3}


def _not_a_server_id(vehicle_id: str) -> str:
    if re.fullmatch(r"[icr]-[0-9a-f]{16}", vehicle_id):
        raise ValueError(
            "shaped like an id the server gives (i-: an instance, c-: a command, r-: a "
            "request), which it would hide wherever either may be named: choose another"
        )
    return vehicle_id


#: The name the server acts under: ``issued_by`` of the commands it sends on its own, the
#: ``actor`` of what it records. No user may have it: the user would pass for the server,
#: and the end of its lease would cancel the server's commands as that user's.
SERVER_ACTOR = "system"


def _not_the_server(username: str) -> str:
    if username == SERVER_ACTOR:
        raise ValueError(
            f"{SERVER_ACTOR!r} is the name the server's own commands and records carry: "
            "choose another"
        )
    return username


class CreateVehicle(WireModel):
    vehicle_id: Annotated[Identifier, AfterValidator(_not_a_server_id)]
    name: Label = Field(default="", max_length=128)
    vehicle_type: Label = Field(default="usv", min_length=1, max_length=32)


class PatchVehicle(WireModel):
    """A registered vehicle's name or type to change (**extension**: a vehicle registered
    with a typo or the wrong type is put right, its history kept). A field this body
    does not have is a 422 naming it, as for :class:`PatchUser`."""

    model_config = ConfigDict(extra="forbid")

    name: Label | None = Field(default=None, min_length=1, max_length=128)
    vehicle_type: Label | None = Field(default=None, min_length=1, max_length=32)

    _no_null = field_validator("name", "vehicle_type", mode="before")(refuse_null)


class VehicleCreated(WireModel):
    vehicle_id: Text
    token: Text


class CreateGateway(WireModel):
    gateway_id: Identifier
    vehicles: VehicleIds = Field(default_factory=list, max_length=1000)


class GatewayCreated(WireModel):
    gateway_id: Text
    token: Text
    vehicles: list[Text] = Field(default_factory=list)


class GatewayView(WireModel):
    gateway_id: Text
    vehicles: list[Text]
    created_at: Timestamp | None = None
    #: Tokens of this gateway that work now (0: revoked until a new one is issued).
    active_tokens: int = 0


class GatewayList(WireModel):
    gateways: list[GatewayView]


#: The shortest password a user is given (a login is checked against argon2 whatever its
#: length; this bounds only the passwords set).
MIN_PASSWORD_CHARS = 8


class CreateUser(WireModel):
    username: Annotated[Identifier, AfterValidator(_not_the_server)]
    role: Role
    vehicles: VehicleIds = Field(default_factory=list, max_length=10000)
    password: Text | None = Field(default=None, min_length=MIN_PASSWORD_CHARS, max_length=256)


class UserCreated(WireModel):
    username: Text
    role: Role
    token: Text
    vehicles: list[Text] = Field(default_factory=list)


class CallerView(WireModel):
    """``GET /api/me``: the user a token acts for (what the console shows and offers)."""

    username: Text
    role: Role
    vehicles: list[Text] = Field(description="the vehicles assigned (an admin sees every one)")
    expires_at: Timestamp | None = Field(
        default=None, description="when the token ends (a session's); null: until revoked"
    )


class UserView(WireModel):
    username: Text
    role: Role
    vehicles: list[Text]
    disabled: bool
    created_at: Timestamp | None = None


class UserList(WireModel):
    users: list[UserView]


class PatchUser(WireModel):
    """The fields to change. A field this body does not have is a 422 naming it: a
    misspelt ``disabld`` must not pass as a change that was made."""

    model_config = ConfigDict(extra="forbid")

    role: Role | None = None
    vehicles: VehicleIds | None = Field(default=None, max_length=10000)
    disabled: StrictBool | None = None
    password: Text | None = Field(default=None, min_length=MIN_PASSWORD_CHARS, max_length=256)

    _no_null = field_validator("role", "vehicles", "disabled", "password", mode="before")(
        refuse_null
    )


class LoginRequest(WireModel):
    username: Text = Field(min_length=1, max_length=64)
    password: Text = Field(min_length=1, max_length=256)


class TokenResult(WireModel):
    access_token: Text
    token_type: Literal["bearer"] = "bearer"
    expires_in: int


class LogoutResult(WireModel):
    """``POST /auth/logout``: whether a session token was ended (an API token is not)."""

    ended: bool


class DeadLetter(WireModel):
    """A record a background loop could not handle, kept aside (``GET /api/dead_letters``)."""

    loop: Text
    record_id: Text
    error: Text
    raw: Text = Field(description="a text rendering of what the record held")
    at: Timestamp


class DeadLetterList(WireModel):
    dead_letters: list[DeadLetter]

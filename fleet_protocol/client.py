"""Operator side: ``/client/*`` bodies and answers (seed Table 1)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    ConfigDict,
    Field,
    StrictInt,
    ValidationInfo,
    field_validator,
    model_validator,
)

from fleet_protocol.commands import CommandObject, CommandSpec
from fleet_protocol.common import Identifier, Sample, Timestamp, WireModel
from fleet_protocol.served import ServedObject
from fleet_protocol.text import Note, Text
from fleet_protocol.upper import ControlInfo, ControlMode, InstanceRef

__all__ = [
    "CancelCommand",
    "ConnectInstance",
    "ConnectInstanceResult",
    "ControlRequest",
    "ControlRequestList",
    "DenyControl",
    "GetFbMessageResult",
    "GetParamResult",
    "GrantControl",
    "InstanceView",
    "OkResult",
    "OperatorHeartbeat",
    "OperatorHeartbeatResult",
    "Presence",
    "QueuedCommand",
    "RevokeResult",
    "SubmitControl",
    "SubmitControlResult",
]

Presence = Literal["online", "stale", "offline", "finished"]


class ConnectInstance(WireModel):
    instance_id: Text | None = Field(default=None, min_length=1, max_length=64)
    vehicle_id: Identifier | None = None

    @model_validator(mode="after")
    def _one_of(self) -> ConnectInstance:
        if not self.instance_id and not self.vehicle_id:
            raise ValueError("give instance_id or vehicle_id")
        return self


class InstanceView(WireModel):
    instance_id: Text
    vehicle_id: Text
    name: Text
    vehicle_type: Text
    capabilities: list[Text]
    presence: Presence
    last_seen: Timestamp | None
    control_mode: ControlMode
    control: ControlInfo | None
    started_at: Timestamp | None = None


class ConnectInstanceResult(WireModel):
    instance: InstanceView


class GetParamResult(WireModel):
    params: ServedObject
    position: Sample | None
    updated_at: Timestamp | None


class SubmitControl(WireModel):
    # A field it does not know is a 422 naming it, not dropped (``ttl`` for ``ttl_s``).
    model_config = ConfigDict(extra="forbid")

    #: An instance named twice is taken once (a stop sent to a vehicle by its id and its
    #: name is one stop, never refused for the repeat).
    instance_ids: list[Annotated[Text, Field(min_length=1, max_length=128)]] = Field(
        min_length=1, max_length=1000
    )
    command: CommandSpec
    ttl_s: StrictInt = Field(default=30, ge=1, le=3600)

    @field_validator("instance_ids")
    @classmethod
    def _wildcard_alone_each_once(cls, ids: list[str]) -> list[str]:
        ids = list(dict.fromkeys(ids))
        if "*" in ids and ids != ["*"]:
            raise ValueError('"*" stands alone in instance_ids')
        return ids

    @field_validator("command")
    @classmethod
    def _wildcard_only_for_stop(cls, command: CommandSpec, info: ValidationInfo) -> CommandSpec:
        if info.data.get("instance_ids") == ["*"] and command.type != "stop":
            raise ValueError('instance_ids ["*"] is for stop only')
        return command


class QueuedCommand(WireModel):
    instance_id: Text
    command_id: Text
    status: Text = "queued"


class SubmitControlResult(WireModel):
    commands: list[QueuedCommand]
    #: (**extension**) What the submit does that its sender may not have meant, in words:
    #: several vehicles sent to one point, or along one path not planned, meet there.
    warnings: list[Text] = Field(default_factory=list)


class GetFbMessageResult(WireModel):
    control_mode: ControlMode
    commands: list[CommandObject]


class CancelCommand(WireModel):
    command_id: Text = Field(min_length=1, max_length=64)


class ControlRequest(WireModel):
    request_id: Text
    username: Text
    instance_id: Text
    requested_at: Timestamp
    #: When the request is dropped if nobody answers it (**extension**).
    expires_at: Timestamp | None = None


class ControlRequestList(WireModel):
    requests: list[ControlRequest]


class GrantControl(InstanceRef):
    # A field it does not know is a 422 naming it (``operator_timeout`` for
    # ``operator_timeout_s`` would grant a lease with no liveness guard).
    model_config = ConfigDict(extra="forbid")

    user: Identifier
    duration_s: StrictInt = Field(ge=1, le=86400)
    #: The lease lapses (and the vehicle holds station) when the holder's client sends no
    #: ``POST /client/heartbeat`` for this long; unset: it runs to its expiry.
    operator_timeout_s: StrictInt | None = Field(default=None, ge=2, le=3600)


class DenyControl(InstanceRef):
    """A field manager declines a pending request for control."""

    user: Identifier
    reason: Note | None = Field(default=None, max_length=200)


class OperatorHeartbeat(WireModel):
    """The holder's client is alive: for each lease it holds on these instances."""

    instance_ids: list[Annotated[Text, Field(min_length=1, max_length=128)]] = Field(
        min_length=1, max_length=1000
    )


class OperatorHeartbeatResult(WireModel):
    #: The instances whose lease the caller holds (its heartbeat counted there).
    held: list[Text]


class OkResult(WireModel):
    ok: bool = True


class RevokeResult(OkResult):
    """``revoke_control``'s answer: ``revoked`` (**extension**) says whether a lease was
    live to end; revoking where nobody holds control is no error, and records nothing."""

    revoked: bool

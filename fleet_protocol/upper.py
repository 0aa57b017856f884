"""Vehicle side: ``/upper/*`` bodies and answers (seed Table 1)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from fleet_protocol.commands import ACK_STATUSES, CommandObject, CommandType
from fleet_protocol.common import Identifier, Sample, Timestamp, WireModel

__all__ = [
    "MAX_SAMPLES_PER_CALL",
    "ControlInfo",
    "ControlMode",
    "FailsafePolicy",
    "FbAck",
    "FinishInstance",
    "FinishInstanceResult",
    "GetControlResult",
    "Heartbeat",
    "HeartbeatResult",
    "InstanceRef",
    "StartInstance",
    "StartInstanceResult",
    "UpdateFbMessage",
    "UpdateFbMessageResult",
    "UpdateParam",
    "UpdateParamResult",
]

ControlMode = Literal["idle", "remote", "local", "failsafe"]
AckStatus = Literal["accepted", "executing", "done", "rejected", "failed"]
assert set(ACK_STATUSES) == set(AckStatus.__args__)  # type: ignore[attr-defined]

MAX_SAMPLES_PER_CALL = 5000
MAX_PARAMS = 512


class InstanceRef(WireModel):
    instance_id: str = Field(min_length=1, max_length=64)


class ControlInfo(WireModel):
    """Who holds remote control of an instance, and until when."""

    holder: str
    granted_by: str
    expires_at: Timestamp


class FailsafePolicy(WireModel):
    """What the vehicle does on its own after ``after_s`` without the server."""

    after_s: float = 30.0
    action: Literal["keep_station", "stop"] = "keep_station"


class StartInstance(WireModel):
    vehicle_id: Identifier
    name: str = Field(default="", max_length=128)
    vehicle_type: str = Field(default="usv", min_length=1, max_length=32)
    capabilities: list[CommandType] = Field(default_factory=list, max_length=16)
    params: dict[str, Any] = Field(default_factory=dict, max_length=MAX_PARAMS)


class StartInstanceResult(WireModel):
    instance_id: str
    resumed: bool
    last_seq: int
    heartbeat_interval_s: float
    stale_after_s: float
    offline_after_s: float
    ack_timeout_s: float
    server_time: Timestamp
    failsafe: FailsafePolicy
    control: ControlInfo | None = None


class FinishInstance(InstanceRef):
    pass


class FinishInstanceResult(WireModel):
    instance_id: str
    state: Literal["finished"] = "finished"


class UpdateParam(InstanceRef):
    params: dict[str, Any] = Field(default_factory=dict, max_length=MAX_PARAMS)
    samples: list[Sample] = Field(default_factory=list, max_length=MAX_SAMPLES_PER_CALL)


class UpdateParamResult(WireModel):
    accepted: int
    duplicates: int
    acked_through_seq: int
    durable_through_seq: int


class GetControlResult(WireModel):
    commands: list[CommandObject]


class FbAck(WireModel):
    command_id: str = Field(min_length=1, max_length=64)
    status: AckStatus
    progress: float | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    detail: str | None = Field(default=None, max_length=512)


class UpdateFbMessage(InstanceRef):
    control_mode: ControlMode | None = None
    acks: list[FbAck] = Field(default_factory=list, max_length=256)


class UpdateFbMessageResult(WireModel):
    ok: bool = True
    abort: list[str] = Field(default_factory=list)


class Heartbeat(InstanceRef):
    pass


class HeartbeatResult(WireModel):
    ok: bool = True
    server_time: Timestamp

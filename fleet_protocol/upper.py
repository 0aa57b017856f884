"""Vehicle side: ``/upper/*`` bodies and answers (seed Table 1)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from fleet_protocol.commands import ACK_STATUSES, CommandObject, CommandType
from fleet_protocol.common import Identifier, Sample, Timestamp, WireModel
from fleet_protocol.values import Params, Text

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


class InstanceRef(WireModel):
    instance_id: Text = Field(min_length=1, max_length=64)


class ControlInfo(WireModel):
    """Who holds remote control of an instance, and until when."""

    holder: Text
    granted_by: Text
    expires_at: Timestamp


class FailsafePolicy(WireModel):
    """What the vehicle does on its own after ``after_s`` without the server."""

    after_s: float = 30.0
    action: Literal["keep_station", "stop"] = "keep_station"


class StartInstance(WireModel):
    """A vehicle starts (or resumes) its instance; ``params``: a free-form object of at most
    ``MAX_PARAMS`` entries (``docs/limits.md``)."""

    vehicle_id: Identifier
    name: Text = Field(default="", max_length=128)
    vehicle_type: Text = Field(default="usv", min_length=1, max_length=32)
    capabilities: list[CommandType] = Field(default_factory=list, max_length=16)
    params: Params = Field(default_factory=dict)


class StartInstanceResult(WireModel):
    instance_id: Text
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
    instance_id: Text
    state: Literal["finished"] = "finished"


class UpdateParam(InstanceRef):
    """Parameters (merged into the instance's) and telemetry samples (``docs/limits.md``)."""

    params: Params = Field(default_factory=dict)
    samples: list[Sample] = Field(default_factory=list, max_length=MAX_SAMPLES_PER_CALL)


class UpdateParamResult(WireModel):
    accepted: int
    duplicates: int
    acked_through_seq: int
    durable_through_seq: int


class GetControlResult(WireModel):
    commands: list[CommandObject]


class FbAck(WireModel):
    command_id: Text = Field(min_length=1, max_length=64)
    status: AckStatus
    progress: float | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    detail: Text | None = Field(default=None, max_length=512)


class UpdateFbMessage(InstanceRef):
    control_mode: ControlMode | None = None
    acks: list[FbAck] = Field(default_factory=list, max_length=256)


class UpdateFbMessageResult(WireModel):
    ok: bool = True
    abort: list[Text] = Field(default_factory=list)


class Heartbeat(InstanceRef):
    pass


class HeartbeatResult(WireModel):
    ok: bool = True
    server_time: Timestamp

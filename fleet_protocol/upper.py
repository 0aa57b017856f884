"""Vehicle side: ``/upper/*`` bodies and answers (seed Table 1)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, StrictBool, StrictFloat, StrictInt

from fleet_protocol.commands import ACK_STATUSES, CommandObject, CommandType
from fleet_protocol.common import Identifier, LatLon, Sample, SampleDoc, Timestamp, WireModel
from fleet_protocol.text import Label, Text
from fleet_protocol.values import Params

__all__ = [
    "MAX_ACKS_PER_CALL",
    "MAX_ACTIVE_COMMANDS",
    "MAX_CLOCK_OFFSET_S",
    "MAX_SAMPLES_PER_CALL",
    "ControlInfo",
    "ControlMode",
    "FailsafeAction",
    "FailsafePolicy",
    "FailsafeView",
    "FbAck",
    "FinishInstance",
    "FinishInstanceResult",
    "GetControlResult",
    "Heartbeat",
    "HeartbeatResult",
    "InstanceRef",
    "SetFailsafe",
    "StartInstance",
    "StartInstanceResult",
    "UpdateFbMessage",
    "UpdateFbMessageResult",
    "UpdateParam",
    "UpdateParamDocs",
    "UpdateParamResult",
    "WhoAmIResult",
]

ControlMode = Literal["idle", "remote", "local", "failsafe"]
#: Acks in one ``update_fbmessage``.
MAX_ACKS_PER_CALL = 256
#: Commands a resuming vehicle names in ``active_commands``: its acks waiting to be sent
#: (at most a call's worth at a time, and more behind them) and the one it carries out.
MAX_ACTIVE_COMMANDS = 1024
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
    #: The lease lapses when the holder's client is silent this long (``None``: never).
    operator_timeout_s: float | None = None


FailsafeAction = Literal["none", "keep_station", "stop", "return_home"]


class FailsafePolicy(WireModel):
    """What the vehicle does on its own after ``after_s`` without the server.

    ``none`` (an AUV that loses its link on every dive), ``keep_station``
    (where it is), ``stop``, or ``return_home`` (``home``; unset: where its
    instance first reported). ``on_breach``: the server sends the same action
    when the vehicle enters a no-go zone or leaves its operating area.
    ``low_battery_pct``: below it, a ``low_battery`` event. ``version`` rises
    with each change; the vehicle acknowledges the version it applies.
    """

    after_s: StrictFloat = Field(default=30.0, gt=0, le=86_400, allow_inf_nan=False)
    action: FailsafeAction = "keep_station"
    home: LatLon | None = None
    on_breach: StrictBool = False
    low_battery_pct: StrictFloat | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    version: StrictInt = Field(default=0, ge=0, le=2**62)


class SetFailsafe(WireModel):
    """``PUT /api/vehicles/{vehicle_id}/failsafe``: the vehicle's whole policy (a field
    left out takes the server's default: ``FLEET_FAILSAFE_AFTER_S``, ``FLEET_FAILSAFE_ACTION``).
    A field it does not know is a 422 naming it: ``acton`` for ``action`` would otherwise
    set the default policy in place of the one meant."""

    model_config = ConfigDict(extra="forbid")

    after_s: StrictFloat | None = Field(default=None, gt=0, le=86_400, allow_inf_nan=False)
    action: FailsafeAction | None = None
    home: LatLon | None = None
    on_breach: StrictBool = False
    low_battery_pct: StrictFloat | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    #: The policy as read may be sent back: its version is taken and ignored (the server
    #: numbers each policy it stores).
    version: Any = Field(default=None, exclude=True, description="ignored (the policy as read)")


class FailsafeView(WireModel):
    """A vehicle's failsafe policy, and whether its live instance applies this version."""

    vehicle_id: Text
    failsafe: FailsafePolicy
    #: The version the vehicle's live instance acknowledged (None: none yet, or no instance).
    acked_version: int | None = None
    acked: bool | None = None
    updated_at: Timestamp | None = None
    updated_by: Text | None = None


class StartInstance(WireModel):
    """A vehicle starts (or resumes) its instance; ``params``: a free-form object of at most
    ``MAX_PARAMS`` entries (``docs/limits.md``)."""

    vehicle_id: Identifier
    #: Empty: the name the vehicle has (as registered, or as its last start gave it).
    name: Label = Field(default="", max_length=128)
    #: None: the type it has (as registered, or as its last start gave it).
    vehicle_type: Label | None = Field(default=None, min_length=1, max_length=32)
    #: None (left out): the ones it has (as its last start gave them; none at its first);
    #: ``[]``: none.
    capabilities: list[CommandType] | None = Field(default=None, max_length=16)
    params: Params = Field(default_factory=dict)
    #: The commands the vehicle still carries out or has an ack to send for. Given (even
    #: empty), every other command of the instance it had acknowledged (``accepted``,
    #: ``executing``) is ``failed``: nothing on the vehicle will finish it. None: no word.
    active_commands: list[Annotated[Text, Field(min_length=1, max_length=64)]] | None = Field(
        default=None, max_length=MAX_ACTIVE_COMMANDS
    )


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
    #: Of ``active_commands``, those the server has ended or does not know: never to be
    #: carried out (as ``update_fbmessage``'s ``abort``).
    abort: list[Text] = Field(default_factory=list)


class FinishInstance(InstanceRef):
    pass


class FinishInstanceResult(WireModel):
    instance_id: Text
    state: Literal["finished"] = "finished"


#: Bound on a vehicle's clock offset: the span of ``Timestamp`` (1970 to 2100) and more.
MAX_CLOCK_OFFSET_S = 5e9


class UpdateParam(InstanceRef):
    """Parameters (merged into the instance's) and telemetry samples (``docs/limits.md``).

    The link's timing (all optional; docs/live.md, "Latency per hop"): ``sent_at``, when
    the vehicle sent the call by its own clock; ``clock_offset_s``, its estimate of the
    server's clock minus its own (from the ``server_time`` of its calls); ``rtt_s``, the
    round trip of its latest call. The server takes the vehicle → server delay from them.
    """

    params: Params = Field(default_factory=dict)
    samples: list[Sample] = Field(default_factory=list, max_length=MAX_SAMPLES_PER_CALL)
    sent_at: Timestamp | None = None
    clock_offset_s: StrictFloat | None = Field(
        default=None, ge=-MAX_CLOCK_OFFSET_S, le=MAX_CLOCK_OFFSET_S, allow_inf_nan=False
    )
    rtt_s: StrictFloat | None = Field(default=None, ge=0, le=86_400, allow_inf_nan=False)


class UpdateParamDocs(UpdateParam):
    """:class:`UpdateParam` as the server reads it: the same fields and rules, each
    sample a plain dict (:data:`~fleet_protocol.common.SampleDoc`). Fields it does not
    know are kept aside (``model_extra``), never used: a call that carries nothing but
    them (``sample`` for ``samples``) is refused rather than answered "0 accepted"."""

    model_config = ConfigDict(extra="allow")

    samples: list[SampleDoc] = Field(default_factory=list, max_length=MAX_SAMPLES_PER_CALL)


class UpdateParamResult(WireModel):
    accepted: int
    duplicates: int
    acked_through_seq: int
    durable_through_seq: int
    #: The server's time as it answered (the vehicle estimates its clock offset from it).
    server_time: Timestamp | None = None


class GetControlResult(WireModel):
    commands: list[CommandObject]
    #: The vehicle's failsafe policy, when it has a version the vehicle has not applied.
    failsafe: FailsafePolicy | None = None
    #: Commands handed to the vehicle that ended on the server since (cancelled,
    #: expired): it stops carrying them out. A long poll returns as soon as there is one.
    abort: list[Text] = Field(default_factory=list)
    #: Who holds remote control now (null: nobody), as ``start_instance`` says it
    #: (**extension**: a vehicle on the HTTP fallback hears of grants and revokes too).
    control: ControlInfo | None = None


class FbAck(WireModel):
    command_id: Text = Field(min_length=1, max_length=64)
    status: AckStatus
    #: How far along: a fraction from 0 (begun) to 1 (done), as the console shows it in %.
    progress: StrictFloat | None = Field(default=None, ge=0, le=1, allow_inf_nan=False)
    detail: Text | None = Field(default=None, max_length=512)
    #: With ``accepted`` for a ``follow_path``: the hash of the path the vehicle stored.
    path_hash: Text | None = Field(default=None, max_length=128)


class UpdateFbMessage(InstanceRef):
    control_mode: ControlMode | None = None
    acks: list[FbAck] = Field(default_factory=list, max_length=MAX_ACKS_PER_CALL)
    #: The version of the failsafe policy the vehicle applies now.
    failsafe_version: StrictInt | None = Field(default=None, ge=0, le=2**62)
    #: When the vehicle entered ``control_mode``, on the server's clock as it estimates it
    #: (**extension**): a mode taken while the link was down is dated by it, not by the
    #: call that says it once the link is back.
    control_mode_since: Timestamp | None = None


class UpdateFbMessageResult(WireModel):
    ok: bool = True
    abort: list[Text] = Field(default_factory=list)


class Heartbeat(InstanceRef):
    pass


class HeartbeatResult(WireModel):
    ok: bool = True
    server_time: Timestamp


class WhoAmIResult(WireModel):
    """``GET /upper/whoami`` and the ``whoami`` op (**extension**): whom a vehicle's or a
    gateway's token acts for. A gateway asks it to refuse, at once, a local unit of a
    vehicle its token does not list."""

    kind: Literal["vehicle", "gateway"]
    vehicle_id: Identifier | None = Field(default=None, description="a vehicle's token")
    gateway_id: Identifier | None = Field(default=None, description="a gateway's token")
    vehicles: list[Identifier] = Field(description="the vehicles it acts for, sorted")

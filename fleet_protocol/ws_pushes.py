"""The server's WebSocket pushes (API.md, "WebSocket"): ``ack``, ``error``, ``command``,
``abort``, ``control``, ``failsafe``, ``event``, ``routes``, ``lagging``; the ops that
come in are in :mod:`fleet_protocol.ws`, which names these too."""

from __future__ import annotations

import functools
from typing import Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    model_serializer,
)
from pydantic_core import PydanticSerializationError, to_json

from fleet_protocol.commands import CommandObject
from fleet_protocol.common import Timestamp
from fleet_protocol.errors import ErrorBody
from fleet_protocol.served import safe_dumps
from fleet_protocol.text import Text
from fleet_protocol.upper import ControlInfo, FailsafePolicy

__all__ = [
    "AbortPush",
    "AckPush",
    "CommandPush",
    "ControlPush",
    "ErrorPush",
    "EventPush",
    "FailsafePush",
    "LaggingPush",
    "Push",
    "RoutesPush",
]


class _Push(BaseModel):
    """A frame from the server. Optional fields left ``None`` are not written."""

    model_config = ConfigDict(extra="ignore", populate_by_name=True)
    _omit_if_none: ClassVar[frozenset[str]] = frozenset()

    @model_serializer(mode="wrap")
    def _omit_none(
        self, handler: SerializerFunctionWrapHandler, info: SerializationInfo
    ) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        for name in self._omit_if_none:
            if data.get(name, 0) is None:
                del data[name]
        return data

    def frame(self) -> str:
        """The JSON text frame; a value JSON cannot hold (data stored by an older version)
        is sent escaped (``fleet_protocol.served.json_safe``), never refused."""
        try:
            return self.model_dump_json()
        except PydanticSerializationError:
            return safe_dumps(self.model_dump(mode="python"))


_ACK_OWN_FIELDS = frozenset({"op", "id", "ok", "error"})


@functools.cache
def _ack_clash(model: type[BaseModel]) -> set[str]:
    """A result model's fields that an ack's own fields take precedence over."""
    return set(_ACK_OWN_FIELDS & model.model_fields.keys())


class AckPush(_Push):
    """The answer to an op with an ``id``; on success, the HTTP answer's fields beside."""

    model_config = ConfigDict(extra="allow")
    _omit_if_none = frozenset({"error"})

    op: Literal["ack"] = "ack"
    id: Text
    ok: bool
    error: ErrorBody | None = None

    @classmethod
    def success(cls, op_id: str, result: BaseModel | dict[str, Any] | None = None) -> AckPush:
        fields = result.model_dump(mode="json") if isinstance(result, BaseModel) else result
        fields = {k: v for k, v in (fields or {}).items() if k not in ("op", "id", "ok", "error")}
        return cls(id=op_id, ok=True, **fields)

    @staticmethod
    def success_frame(op_id: str, result: BaseModel | dict[str, Any] | None = None) -> str:
        """``success(...).frame()`` without building the model (the hot path of every op)."""
        head = '{"op":"ack","id":' + to_json(op_id).decode() + ',"ok":true'
        if isinstance(result, BaseModel):
            clash = _ack_clash(type(result))
            body = result.model_dump_json(exclude=clash or None)  # in Rust
        elif result:
            if not _ACK_OWN_FIELDS.isdisjoint(result):
                result = {k: v for k, v in result.items() if k not in _ACK_OWN_FIELDS}
            body = to_json(result).decode()
        else:
            body = "{}"
        return head + "}" if body == "{}" else head + "," + body[1:]

    @classmethod
    def failure(cls, op_id: str, error: ErrorBody) -> AckPush:
        return cls(id=op_id, ok=False, error=error)


class ErrorPush(_Push):
    """A failed op that carried no ``id``."""

    op: Literal["error"] = "error"
    error: ErrorBody


class CommandPush(_Push, CommandObject):
    """A command object, pushed to the vehicle the moment it is accepted."""

    op: Literal["command"] = "command"

    @property
    def critical(self) -> bool:
        """A ``stop`` is never dropped by a queue bound."""
        return self.type == "stop"


class AbortPush(_Push):
    """Commands handed to the vehicle that ended on the server (cancelled, expired):
    it stops carrying them out at once."""

    op: Literal["abort"] = "abort"
    instance_id: Text
    command_ids: list[Text] = Field(min_length=1)

    @property
    def critical(self) -> bool:
        """Like a ``stop``, never dropped by a queue bound."""
        return True


class ControlPush(_Push):
    """Who holds remote control of the instance now (``null``: nobody)."""

    op: Literal["control"] = "control"
    instance_id: Text
    control: ControlInfo | None = None


class FailsafePush(_Push):
    """The vehicle's failsafe policy changed: apply it, and acknowledge its version."""

    op: Literal["failsafe"] = "failsafe"
    instance_id: Text
    failsafe: FailsafePolicy


class EventPush(_Push):
    """A message on a topic. A gateway passes the events from above down to its units as
    they came, rebuilt from this model: ``source`` is one of its fields, and a field it
    does not know (a newer server's) is kept too, not dropped on the way."""

    model_config = ConfigDict(extra="allow")
    _omit_if_none = frozenset({"snapshot", "ts", "source"})

    op: Literal["event"] = "event"
    topic: Text
    data: Any = None
    #: ``true`` on the current state sent first after a subscribe.
    snapshot: bool | None = None
    #: The server's time of the change (none on an event between a gateway's units).
    ts: Timestamp | None = None
    #: The unit that published it (``vehicle:<id>``, ``gateway:<id>``, ``user:<name>``);
    #: none on a topic the server writes, and on an event between a gateway's units.
    source: Text | None = None


class RoutesPush(_Push):
    """The part of the routing table this unit takes part in.

    ``produces``: each topic it registered, with the units consuming it;
    ``consumes``: each topic it subscribed to, with the units producing it;
    for a gateway, ``forward_up`` (what it sends to the cloud) and
    ``forward_down`` (what it delivers to its units from above).
    """

    op: Literal["routes"] = "routes"
    unit: Text
    produces: dict[Text, list[Text]] = Field(default_factory=dict)
    consumes: dict[Text, list[Text]] = Field(default_factory=dict)
    forward_up: list[Text] = Field(default_factory=list)
    forward_down: list[Text] = Field(default_factory=list)


class LaggingPush(_Push):
    """Messages were dropped for this connection since the last ``lagging``."""

    _omit_if_none = frozenset({"total"})

    op: Literal["lagging"] = "lagging"
    dropped: int = Field(ge=1)
    #: Dropped since the connection opened.
    total: int | None = None


Push = (
    AckPush
    | ErrorPush
    | CommandPush
    | AbortPush
    | ControlPush
    | FailsafePush
    | EventPush
    | RoutesPush
    | LaggingPush
)

"""What a local unit is told when the gateway refuses it something, or the server does.

The gateway refuses here what the server would refuse above, in the server's
words (an ``invalid`` or ``forbidden`` error naming the ``topic`` field), for
two reasons: a unit's publish kept among the local units never reaches the
server, and a subscription taken while the cloud link is down is acked
``local_only`` and refused above only at the replay, when nobody is waiting
for an ack. What the server refuses at the replay is told to the units that
held it with an ``error`` push (:func:`dropped`), since they asked long before,
and so is what the vehicles the token acts for turn out not to allow. Pure.
"""

from __future__ import annotations

from fleet_protocol import ErrorBody
from fleet_protocol.topics import is_media_topic, shape_problem
from fleet_protocol.ws import PublishOp, RegisterOp, SubscribeOp
from vehicle_client.gateway.forwarding import read_refusal, write_refusal

__all__ = ["TOKEN_REFUSED", "dropped", "media_refusal", "op_refusal", "refusal"]

#: The close reason a unit gets (with 4401) when the server refused the gateway's own
#: token: the gateway stops, and connecting again will not help until it has another.
TOKEN_REFUSED = "the gateway's token was refused (revoked or expired): the gateway stops"


def refusal(code: str, message: str, field: str, detail: str | None = None) -> ErrorBody:
    """An op refused for one of its fields, named as the server names it (``detail``: the
    field's own sentence, when it is not ``message``)."""
    said = detail if detail is not None else message
    return ErrorBody(code=code, message=message, details=[{"field": field, "message": said}])


def op_refusal(vehicle_id: str, op: object, acts_for: frozenset[str] | None) -> ErrorBody | None:
    """Why the gateway refuses a topic op of a unit of ``vehicle_id`` before it goes
    anywhere (``None``: it does not): a topic the unit may not write (``publish``,
    ``register``) or the gateway may not read (``subscribe``; ``acts_for``: the
    vehicles its token acts for, ``None`` while not known), JSON on a media topic. A
    topic of no known shape is ``invalid``, as the server says, whoever asks."""
    if isinstance(op, PublishOp):
        named = [("topic", op.topic)]
    elif isinstance(op, RegisterOp | SubscribeOp):
        named = [(f"topics.{index}", topic) for index, topic in enumerate(op.topics)]
    else:
        named = []
    for field, topic in named:
        if (problem := shape_problem(topic)) is not None:
            return refusal("invalid", f"{topic}: {problem}", field)
    if isinstance(op, PublishOp):
        if (reason := write_refusal(vehicle_id, op.topic)) is not None:
            return refusal("forbidden", reason, "topic", f"{op.topic}: {reason}")
    if isinstance(op, RegisterOp):
        for index, topic in enumerate(op.topics):  # a list's field named as the server does
            if (reason := write_refusal(vehicle_id, topic)) is not None:
                return refusal("forbidden", reason, f"topics.{index}", f"{topic}: {reason}")
    if isinstance(op, SubscribeOp):
        for index, topic in enumerate(op.topics):
            if (reason := read_refusal(topic, acts_for)) is not None:
                return refusal("forbidden", reason, f"topics.{index}", f"{topic}: {reason}")
    if isinstance(op, PublishOp) and is_media_topic(op.topic):
        return refusal("invalid", f"{op.topic} is a media topic: send binary frames on it", "topic")
    return None


def media_refusal(vehicle_id: str, topic: str) -> ErrorBody | None:
    """Why a media frame of a unit of ``vehicle_id`` on ``topic`` goes nowhere (``None``:
    it goes): JSON belongs on the topic, or the unit may not write it."""
    if not is_media_topic(topic):
        return refusal("invalid", f"{topic} is not a media topic: publish JSON on it", "topic")
    if (reason := write_refusal(vehicle_id, topic)) is not None:
        return refusal("forbidden", reason, "topic")
    return None


def dropped(topic: str, code: str, why: str) -> ErrorBody:
    """A subscription a unit held and the gateway let go of as its link came back: the
    vehicles its token acts for (the server's ``whoami``) do not allow it, or the
    server refused it when sent again. ``code`` and ``why``: the refusal's."""
    return refusal(code, f"{topic}: subscription dropped: {why}", "topic", f"{topic}: {why}")

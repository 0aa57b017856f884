"""Topic names: their grammar, the namespaces, and which topics carry media.

A topic is 1 to 8 segments of ``[a-z0-9_-]`` joined by ``/``, at most 128
characters, with no wildcards (the grammar, checked here). The first segment
is the namespace; the server's rules give meaning to these five (a topic
elsewhere is well formed but nobody may write it):

- ``fleet``: presence changes of the whole fleet, written by the server;
- ``zones``: that the operating areas and no-go zones changed (**extension**),
  written by the server;
- ``vehicle/<vehicle_id>/...``: what a vehicle produces (and, for
  ``telemetry``, ``commands``, ``control`` and ``events``, what the server
  says about it);
- ``user/<username>/...``: what a person or a processing worker produces;
- ``gateway/<gateway_id>/...``: what a gateway produces of its own.

Media topics (camera frames, sonar images) travel as binary frames with
latest-wins delivery. A topic is a media topic when one of its segments
after the namespace and its owner is a media kind: ``vehicle/usv-1/camera``,
``vehicle/usv-1/camera/front``, ``user/seg-worker/image/mask``.

Who may read which topic (:func:`read_refusal`) is here too, as one rule: the server
judges every subscription by it, and a gateway judges by it what it can tell before
the server does (its units subscribe while its link is down). Who may write is the
server's alone (``server.domain.topics``). Pure functions only.
"""

from __future__ import annotations

import functools
import re
from collections import OrderedDict
from collections.abc import Mapping
from typing import Annotated, Generic, Protocol, TypeVar

from pydantic import AfterValidator

__all__ = [
    "KEEP_MAX_BYTES",
    "MAX_TOPIC_CHARS",
    "MAX_TOPIC_SEGMENTS",
    "MEDIA_KINDS",
    "NAMESPACES",
    "SERVER_ONLY_VEHICLE_TOPICS",
    "Kept",
    "Reader",
    "Topic",
    "is_media_topic",
    "read_refusal",
    "shape_problem",
    "split_topic",
    "topic_owner",
    "validate_topic",
    "vehicle_topic",
]

MAX_TOPIC_CHARS = 128
MAX_TOPIC_SEGMENTS = 8
_SEGMENT = re.compile(r"^[a-z0-9_-]+$")

NAMESPACES = frozenset({"fleet", "zones", "vehicle", "user", "gateway"})
#: ``vehicle/<id>/<kind>`` (and below) that the server alone writes.
SERVER_ONLY_VEHICLE_TOPICS = frozenset({"telemetry", "commands", "control", "events"})
#: A segment (after namespace and owner) that makes a topic a media topic.
MEDIA_KINDS = frozenset({"camera", "sonar", "image", "video"})


def split_topic(topic: str) -> list[str]:
    """The segments of a valid topic; ``ValueError`` saying why otherwise."""
    if not isinstance(topic, str):
        raise ValueError("a topic is a string")
    return list(_segments(topic))


@functools.lru_cache(maxsize=16384)
def _segments(topic: str) -> tuple[str, ...]:
    """Checked once per distinct topic: the same few topics carry most messages."""
    if not topic:
        raise ValueError("a topic is not empty")
    if len(topic) > MAX_TOPIC_CHARS:
        raise ValueError(f"a topic has at most {MAX_TOPIC_CHARS} characters")
    segments = topic.split("/")
    if len(segments) > MAX_TOPIC_SEGMENTS:
        raise ValueError(f"a topic has at most {MAX_TOPIC_SEGMENTS} segments")
    for segment in segments:
        if not segment:
            raise ValueError("a topic has no empty segment (no leading, trailing or double '/')")
        if not _SEGMENT.match(segment):
            raise ValueError(
                f"topic segment {segment[:32]!r} may hold only a-z, 0-9, '_' and '-' (no wildcards)"
            )
    return tuple(segments)


def validate_topic(topic: str) -> str:
    if not isinstance(topic, str):
        raise ValueError("a topic is a string")
    _segments(topic)
    return topic


#: A validated topic name, for pydantic fields.
Topic = Annotated[str, AfterValidator(validate_topic)]


def topic_owner(topic: str) -> tuple[str, str | None]:
    """``(namespace, owner id)`` of a valid topic.

    ``("vehicle", "usv-1")`` for ``vehicle/usv-1/camera``; the owner is
    ``None`` when the topic has no segment past its namespace.
    """
    segments = topic.split("/")
    return segments[0], (segments[1] if len(segments) > 1 else None)


@functools.lru_cache(maxsize=16384)
def is_media_topic(topic: str) -> bool:
    """Whether a (valid) topic carries media, delivered as binary frames, latest wins."""
    segments = topic.split("/")
    return any(segment in MEDIA_KINDS for segment in segments[2:])


def shape_problem(topic: str) -> str | None:
    """Why ``topic`` names no topic anybody may read or write (the same for every caller:
    a 422, not a refusal of rights); ``None`` for one of a known shape."""
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace in ("fleet", "zones"):
        if len(segments) > 1:
            return f"there are no topics under '{namespace}/': '{namespace}' is one topic"
        return None
    if namespace not in ("vehicle", "user", "gateway"):
        return (
            f"there are no topics under '{namespace}/': a topic is fleet, zones, or under "
            "vehicle/<id>/, user/<username>/ or gateway/<id>/"
        )
    if len(segments) < 3:
        return f"a topic under '{namespace}/' is '{namespace}/<id>/<name>'"
    return None


class Reader(Protocol):
    """Who subscribes, as far as the read rule cares."""

    @property
    def kind(self) -> str: ...  # "user" | "vehicle" | "gateway"

    @property
    def name(self) -> str: ...

    @property
    def is_admin(self) -> bool: ...

    def reads_vehicle(self, vehicle_id: str) -> bool | None:
        """Whether it may read what vehicle ``vehicle_id`` produces (a user assigned to
        it or an admin, the vehicle itself, a gateway listing it); ``None``: that
        cannot be told here."""
        ...


def read_refusal(
    reader: Reader, topic: str, gateway_units: Mapping[str, frozenset[str]] | None
) -> str | None:
    """Why ``reader`` may not subscribe to ``topic``; ``None`` if it may, or if that
    cannot be told here (a vehicle the reader cannot judge, ``gateway_units`` None).

    - ``fleet`` and ``zones`` are for users;
    - ``vehicle/<id>/...`` needs read access to that vehicle;
    - ``user/<username>/...``: that user and admins, and a user's topic about a
      vehicle (``user/<username>/<name>/<vehicle_id>[/...]``) whoever reads that vehicle;
    - ``gateway/<gateway_id>/...``: that gateway, admins, and whoever reads one of the
      gateway's vehicles (``gateway_units``: the vehicles of each gateway named; one
      missing has none)."""
    if (problem := shape_problem(topic)) is not None:
        return problem
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace in ("fleet", "zones"):
        return None if reader.kind == "user" else f"'{namespace}' is for users"
    owner = segments[1]
    if namespace == "vehicle":
        may = reader.reads_vehicle(owner) is not False
        return None if may else f"no read access to vehicle {owner}"
    if reader.is_admin:
        return None
    if namespace == "user":
        if reader.kind == "user" and reader.name == owner:
            return None
        if len(segments) >= 4 and reader.reads_vehicle(segments[3]) is not False:
            return None  # a user's results about a vehicle its readers may read
        return f"only {owner} (and admins) read 'user/{owner}/', but for a vehicle's readers"
    if (reader.kind == "gateway" and reader.name == owner) or gateway_units is None:
        return None
    if any(reader.reads_vehicle(v) is not False for v in gateway_units.get(owner, ())):
        return None
    return f"only gateway {owner}, its units and their readers read 'gateway/{owner}/'"


def vehicle_topic(vehicle_id: str, kind: str) -> str:
    """``vehicle/<vehicle_id>/<kind>``, e.g. ``vehicle_topic("usv-1", "telemetry")``."""
    return validate_topic(f"vehicle/{vehicle_id}/{kind}")


#: A topic's state (its latest kept message, the first a new subscriber gets) has at most
#: this many bytes of JSON: a larger message is not kept, and the one before it is no
#: longer the latest (docs/live.md). The server's bus and a gateway keep states alike.
KEEP_MAX_BYTES = 64 * 1024

M = TypeVar("M")


class Kept(Generic[M]):
    """Each topic's latest kept message, within a budget of bytes (the topic written on
    longest ago goes first when it is passed)."""

    def __init__(self, budget_bytes: int) -> None:
        self.budget_bytes = budget_bytes
        self.bytes = 0
        self._latest: OrderedDict[str, tuple[M, int]] = OrderedDict()

    def put(self, topic: str, message: M | None, size: int) -> None:
        """``message`` (``size`` bytes of JSON) is the topic's latest; None: forget it."""
        old = self._latest.pop(topic, None)
        if old is not None:
            self.bytes -= old[1]
        if message is None or size > KEEP_MAX_BYTES:
            return
        self._latest[topic] = (message, size)
        self.bytes += size
        while self.bytes > self.budget_bytes:
            _, (_, gone) = self._latest.popitem(last=False)
            self.bytes -= gone

    def get(self, topic: str) -> M | None:
        found = self._latest.get(topic)
        return found[0] if found is not None else None

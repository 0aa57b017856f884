"""One instance as a replica holds it in memory, and how it maps to its stored document."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import Sample
from server.domain.latency import LinkDelay
from server.domain.presence import Presence


@dataclass(slots=True)  # 10,000 of them, walked by every sweep: no __dict__ each
class InstanceState:
    instance_id: str
    vehicle_id: str
    name: str
    vehicle_type: str
    capabilities: list[str]
    started_at: datetime
    params: dict[str, Any] = field(default_factory=dict)
    params_updated_at: datetime | None = None
    last_seen: datetime | None = None
    control_mode: str = "idle"
    #: When the vehicle says it entered ``control_mode`` (None: it did not say).
    control_mode_since: datetime | None = None
    position: dict[str, Any] | None = None
    finished_at: datetime | None = None
    presence: Presence = "offline"  # the presence last told
    presence_seq: int = 0  # how many presence changes were told (the last one's seq)
    polling: int = 0  # open long polls: contact while open
    dirty: bool = False  # params or control mode changed: written at the next sweep
    moved: bool = False  # last_seen or position moved: written every persist_interval_s
    saved_at: float = 0.0  # monotonic time of the last write
    #: How often its contact is written back (``contact_write_s``, a little shorter
    #: per instance: see ``server.services.pacing.period_of``).
    contact_every_s: float = 0.0
    #: The link delay measured on this replica (kept in memory only, never written).
    link: LinkDelay = field(default_factory=LinkDelay)
    #: The failsafe version the vehicle was last told on this replica (``start_instance``'s
    #: answer, a long poll's; memory only): a version it was told and has not acknowledged
    #: ends no long poll early.
    failsafe_told: int | None = None
    #: A command with ``max_drift_m`` waits for a current position (memory only).
    drift_held: bool = False
    #: The server's clock minus the vehicle's, in seconds, as the vehicle last said
    #: (``clock_offset_s`` of its calls; memory only). Its samples are dated by its clock.
    clock_offset_s: float = 0.0
    #: Monotonic time this replica's write of the name or type ended (memory only): a
    #: read of the store begun before it may hold the former ones.
    named_at: float = 0.0
    #: Monotonic time this replica's last write of the whole record ended, infinite
    #: while one is under way (memory only): a read of the store begun before it may
    #: hold the former parameters, capabilities and control mode.
    written_at: float = 0.0

    @property
    def finished(self) -> bool:
        return self.finished_at is not None

    def vehicle_clock(self, now: datetime) -> datetime:
        """The server's ``now`` by the vehicle's clock (which dates its samples)."""
        if not self.clock_offset_s:
            return now
        return now - timedelta(seconds=self.clock_offset_s)

    def position_json(self) -> dict[str, Any] | None:
        if self.position is None:
            return None
        return Sample.from_stored(self.position).model_dump(mode="json", exclude_none=True)

    def to_doc(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id,
            "vehicle_id": self.vehicle_id,
            "name": self.name,
            "vehicle_type": self.vehicle_type,
            "capabilities": self.capabilities,
            "started_at": self.started_at,
            "params": self.params,
            "params_updated_at": self.params_updated_at,
            "last_seen": self.last_seen,
            "control_mode": self.control_mode,
            "control_mode_since": self.control_mode_since,
            "position": self.position,
            "finished_at": self.finished_at,
        }

    def contact_doc(self) -> dict[str, Any]:
        """The fields that move with every frame (``moved``): a write of these alone."""
        return {"last_seen": self.last_seen, "position": self.position}

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> InstanceState:
        fields: dict[str, Any] = {
            k: doc.get(k)
            for k in (
                "instance_id",
                "vehicle_id",
                "name",
                "vehicle_type",
                "capabilities",
                "started_at",
                "params",
                "params_updated_at",
                "last_seen",
                "control_mode",
                "control_mode_since",
                "position",
                "finished_at",
            )
        }
        fields["params"] = fields["params"] or {}
        fields["capabilities"] = fields["capabilities"] or []
        fields["control_mode"] = fields["control_mode"] or "idle"
        fields["presence_seq"] = doc.get("presence_seq") or 0
        return cls(**fields)

    def merge_contact(self, doc: dict[str, Any]) -> None:
        """Take the later contact and position of a stored copy (several replicas)."""
        seen = doc.get("last_seen")
        if seen is not None and (self.last_seen is None or seen > self.last_seen):
            self.last_seen = seen
        stored = doc.get("position")
        if stored is not None and (self.position is None or stored["ts"] > self.position["ts"]):
            self.position = stored

    def merge_presence(self, doc: dict[str, Any]) -> None:
        """Take a later presence change told by another replica, as the record notes it."""
        seq = doc.get("presence_seq") or 0
        if seq > self.presence_seq and doc.get("presence") and not self.finished:
            self.presence, self.presence_seq = doc["presence"], seq

    def merge(self, doc: dict[str, Any], read_at: float | None = None) -> None:
        """Catch up with the store's copy, written by another replica (several replicas).

        What this replica changed and has not written yet (``dirty``), or was writing
        when the read began (``written_at``), stays. The name
        and type are the store's: they are written at once wherever they change; but
        not from a read begun (``read_at``, monotonic) before this replica's own write
        of them ended, which may hold the former ones (an admin's rename was undone in
        the copy so: seen under load with two replicas on FerretDB).
        """
        stored = InstanceState.from_doc(doc)
        if read_at is None or read_at >= self.named_at:
            self.name, self.vehicle_type = stored.name, stored.vehicle_type
        # Nor from a read begun before this replica's own write of them ended (a
        # vehicle's parameters read back empty while their write was under way: seen
        # under load on FerretDB).
        if not self.dirty and (read_at is None or read_at >= self.written_at):
            self.capabilities, self.params = stored.capabilities, stored.params
            self.params_updated_at, self.control_mode = (
                stored.params_updated_at,
                stored.control_mode,
            )
            self.control_mode_since = stored.control_mode_since
        self.merge_contact(doc)
        self.merge_presence(doc)
        if doc.get("finished_at") is not None and self.finished_at is None:
            self.finished_at = doc["finished_at"]
            self.presence = "finished"

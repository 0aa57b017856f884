"""A small in-memory stand-in for the server's ``/upper/*``, served through httpx.MockTransport.

It keeps to API.md's vehicle side: seq high-water mark with duplicates
counted, ``durable_through_seq`` lagging by ``durable_lag`` samples, long
poll on ``get_control``, commands handed out until acknowledged, and the
error envelope. ``down`` makes every call fail as a refused connection.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Any

import httpx

from fleet_protocol.common import format_ts, utcnow

TOKEN = "vehicle-token-for-tests"


@dataclass
class FakeUpper:
    vehicle_id: str = "usv-1"
    last_seq: int = 0
    durable_lag: int = 0
    failsafe_after_s: float = 30.0
    down: bool = False
    #: Refuse any update_param that carries params (422 naming ``params``), as a server
    #: whose bound on a vehicle's parameters they would pass; counted.
    refuse_params: bool = False
    refused_params: int = 0
    stored: list[dict[str, Any]] = field(default_factory=list)
    duplicates: int = 0
    params: dict[str, Any] = field(default_factory=dict)
    acks: list[dict[str, Any]] = field(default_factory=list)
    modes: list[str] = field(default_factory=list)
    abort: set[str] = field(default_factory=set)
    starts: int = 0
    commands: list[dict[str, Any]] = field(default_factory=list)
    _acked: set[str] = field(default_factory=set)
    _new_command: asyncio.Event = field(default_factory=asyncio.Event)

    def transport(self) -> httpx.MockTransport:
        return httpx.MockTransport(self.handle)

    def add_command(self, kind: str, args: dict[str, Any], ttl_s: float = 60) -> str:
        now = utcnow()
        cid = f"cmd-{len(self.commands) + 1}"
        self.commands.append(
            {
                "command_id": cid,
                "instance_id": "inst-1",
                "type": kind,
                "args": args,
                "status": "queued",
                "issued_by": "op",
                "issued_at": format_ts(now),
                "expires_at": format_ts(now + timedelta(seconds=ttl_s)),
            }
        )
        self._new_command.set()
        return cid

    def statuses(self, command_id: str) -> list[str]:
        return [a["status"] for a in self.acks if a["command_id"] == command_id]

    def stored_seqs(self) -> list[int]:
        return [s["seq"] for s in self.stored]

    async def handle(self, request: httpx.Request) -> httpx.Response:
        if self.down:
            raise httpx.ConnectError("connection refused", request=request)
        if request.headers.get("authorization") != f"Bearer {TOKEN}":
            return _error(401, "unauthorized", "bad token")
        path = request.url.path
        body = json.loads(request.content) if request.content else {}
        if path == "/upper/start_instance":
            self.starts += 1
            return httpx.Response(200, json=self._start())
        if path == "/upper/heartbeat":
            return httpx.Response(200, json={"ok": True, "server_time": format_ts(utcnow())})
        if path == "/upper/update_param":
            if self.refuse_params and body.get("params"):
                self.refused_params += 1
                details = [{"field": "params", "message": "at most 512 parameters"}]
                return _error(422, "invalid", "params: too many", details)
            return httpx.Response(200, json=self._ingest(body))
        if path == "/upper/update_fbmessage":
            self.modes.append(body.get("control_mode"))
            self.acks.extend(body.get("acks", []))
            self._acked.update(a["command_id"] for a in body.get("acks", []))
            mentioned = {a["command_id"] for a in body.get("acks", [])}
            return httpx.Response(200, json={"ok": True, "abort": sorted(self.abort & mentioned)})
        if path == "/upper/get_control":
            wait_s = float(request.url.params.get("wait_s", "0"))
            return httpx.Response(200, json={"commands": await self._pending(wait_s)})
        return _error(404, "not_found", path)

    def _start(self) -> dict[str, Any]:
        return {
            "instance_id": "inst-1",
            "resumed": self.starts > 1,
            "last_seq": self.last_seq,
            "heartbeat_interval_s": 0.2,
            "stale_after_s": 3,
            "offline_after_s": 10,
            "ack_timeout_s": 10,
            "server_time": format_ts(utcnow()),
            "failsafe": {"after_s": self.failsafe_after_s, "action": "keep_station"},
            "control": None,
        }

    def _ingest(self, body: dict[str, Any]) -> dict[str, Any]:
        accepted = 0
        for sample in body.get("samples", []):
            if sample["seq"] <= self.last_seq:
                self.duplicates += 1
                continue
            self.stored.append(sample)
            self.last_seq = sample["seq"]
            accepted += 1
        for key, value in body.get("params", {}).items():
            if value is None:
                self.params.pop(key, None)
            else:
                self.params[key] = value
        return {
            "accepted": accepted,
            "duplicates": self.duplicates,
            "acked_through_seq": self.last_seq,
            "durable_through_seq": max(0, self.last_seq - self.durable_lag),
        }

    async def _pending(self, wait_s: float) -> list[dict[str, Any]]:
        deadline = asyncio.get_running_loop().time() + wait_s
        while True:
            pending = [c for c in self.commands if c["command_id"] not in self._acked]
            left = deadline - asyncio.get_running_loop().time()
            if pending or left <= 0:
                return pending
            self._new_command.clear()
            try:
                await asyncio.wait_for(self._new_command.wait(), left)
            except TimeoutError:
                return []


def _error(status: int, code: str, message: str, details: Any = None) -> httpx.Response:
    body = {"code": code, "message": message, "details": details}
    return httpx.Response(status, json={"error": body})

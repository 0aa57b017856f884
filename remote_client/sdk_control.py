"""The SDK's calls on remote control: request it, grant or deny it (a field manager), revoke
or release it, and keep a lease alive. A part of :class:`~remote_client.sdk.FleetClient`."""

from __future__ import annotations

import asyncio

from remote_client.sdk_session import Body, OneOrMany, Session, given, listed

__all__ = ["ControlCalls"]


class ControlCalls(Session):
    """Who may command a vehicle remotely (``docs/api.md``, "Arbitration")."""

    async def request_control(self, instance_id: str) -> Body:
        return await self._on_instance("request_control", instance_id)

    async def control_requests(self, instance_id: str | None = None, *, mine: bool = False) -> Body:
        """``{"requests": [...]}``: the pending ones the caller may answer; ``mine``: the
        caller's own, not answered yet (each says when it is dropped: ``expires_at``)."""
        params: dict[str, str] = {"instance_id": instance_id} if instance_id else {}
        if mine:
            params["mine"] = "true"
        body: Body = await self.call("GET", "/client/control_requests", params=params)
        return body

    async def grant_control(
        self,
        instance_id: str,
        user: str,
        duration_s: int = 3600,
        *,
        operator_timeout_s: int | None = None,
    ) -> Body:
        """The lease ``{holder, granted_by, expires_at, operator_timeout_s}`` (a field
        manager or an admin). With ``operator_timeout_s`` it lapses when the holder's
        client sends no heartbeat (:meth:`keep_leases_alive`) for that long."""
        body = {"instance_id": instance_id, "user": user, "duration_s": duration_s} | given(
            operator_timeout_s=operator_timeout_s
        )
        answer: Body = await self.call("POST", "/client/grant_control", json=body)
        return answer

    async def deny_control(self, instance_id: str, user: str, reason: str | None = None) -> Body:
        """Decline ``user``'s pending request for control (a field manager, an admin)."""
        body = {"instance_id": instance_id, "user": user} | given(reason=reason)
        answer: Body = await self.call("POST", "/client/deny_control", json=body)
        return answer

    async def revoke_control(self, instance_id: str) -> Body:
        return await self._on_instance("revoke_control", instance_id)

    async def release_control(self, instance_id: str) -> Body:
        return await self._on_instance("release_control", instance_id)

    async def _on_instance(self, route: str, instance_id: str) -> Body:
        body: Body = await self.call("POST", f"/client/{route}", json={"instance_id": instance_id})
        return body

    async def me(self) -> Body:
        """The user this token acts for: ``username``, ``role``, ``vehicles``."""
        body: Body = await self.call("GET", "/api/me")
        return body

    async def heartbeat(self, instance_ids: OneOrMany) -> list[str]:
        """This client is alive: for the leases the caller holds on these instances; the
        instances where it holds one."""
        body: Body = await self.call(
            "POST", "/client/heartbeat", json={"instance_ids": listed(instance_ids)}
        )
        return list(body["held"])

    async def keep_leases_alive(self, every_s: float | None = None) -> None:
        """Until cancelled: heartbeats for every lease the caller holds, a third of the
        shortest ``operator_timeout_s`` apart (``every_s``: that instead). A lease granted
        with an operator timeout lapses when its holder's client stops: run this while
        you hold control."""
        username = (await self.me())["username"]
        while True:
            held = [
                (v["instance_id"], v["control"].get("operator_timeout_s"))
                for v in (await self.call("GET", "/api/vehicles"))["vehicles"]
                if v.get("control") and v["control"].get("holder") == username
            ]
            if held:
                await self.heartbeat([instance_id for instance_id, _ in held])
            timeouts = [t for _, t in held if t]
            wait = every_s or (min(timeouts) / 3 if timeouts else 5.0)
            await asyncio.sleep(max(0.5, min(wait, 10.0)))

"""``/upper/*`` over HTTP with httpx (injectable transport for tests)."""

from __future__ import annotations

import logging
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel, ValidationError

from fleet_protocol import (
    FinishInstanceResult,
    GetControlResult,
    HeartbeatResult,
    StartInstance,
    StartInstanceResult,
    UpdateFbMessage,
    UpdateFbMessageResult,
    UpdateParam,
    UpdateParamResult,
)
from vehicle_client.errors import (
    CHECK_TOKEN,
    FatalError,
    Refused,
    RetryableError,
    SessionLost,
    TokenRefused,
    refused_fields,
)

log = logging.getLogger(__name__)
M = TypeVar("M", bound=BaseModel)

#: Seconds allowed for an ordinary call; a long poll gets its wait on top.
CALL_TIMEOUT_S = 10.0


def _error_text(response: httpx.Response) -> tuple[str, str]:
    try:
        body = response.json()["error"]
        return str(body.get("code", "")), str(body.get("message", ""))
    except (ValueError, KeyError, TypeError, AttributeError):
        return "", " ".join(response.text[:200].split())  # a web page's lines: one line


def _error_details(response: httpx.Response) -> object:
    try:
        return response.json()["error"].get("details")
    except (ValueError, KeyError, TypeError, AttributeError):
        return None


def _retry_after(response: httpx.Response) -> float | None:
    try:
        return float(response.headers["retry-after"])
    except (KeyError, ValueError):
        return None


class HttpTransport:
    """One ``httpx.AsyncClient`` for all calls; shared by a gateway's vehicles."""

    kind = "http"

    def __init__(
        self,
        server: str,
        token: str,
        *,
        transport: httpx.AsyncBaseTransport | None = None,
        client: httpx.AsyncClient | None = None,
    ) -> None:
        if not server.startswith(("http://", "https://")):
            raise FatalError(f"--server must be an http(s) URL, got {server!r}")
        if not token:
            raise FatalError("no token: give --token (or FLEET_AGENT_TOKEN)")
        self._own = client is None
        self._client = client or httpx.AsyncClient(
            base_url=server.rstrip("/"),
            transport=transport,
            timeout=CALL_TIMEOUT_S,
        )
        self._headers = {"Authorization": f"Bearer {token}"}

    async def aclose(self) -> None:
        if self._own:
            await self._client.aclose()

    async def _call(
        self,
        method: str,
        path: str,
        answer: type[M],
        *,
        json: Any = None,
        params: dict[str, Any] | None = None,
        limit_s: float = CALL_TIMEOUT_S,
    ) -> M:
        try:
            response = await self._client.request(
                method,
                path,
                json=json,
                params=params,
                headers=self._headers,
                timeout=limit_s,
            )
        except httpx.TimeoutException as exc:
            raise RetryableError(f"{path}: timed out") from exc
        except httpx.TransportError as exc:
            why = str(exc) or "the connection broke"  # httpx's ReadError often says nothing
            raise RetryableError(f"{path}: {type(exc).__name__}: {why}") from exc
        status = response.status_code
        if status < 300:
            try:
                return answer.model_validate(response.json())
            except (ValueError, ValidationError) as exc:
                raise RetryableError(f"{path}: unreadable answer: {exc}") from exc
        code, message = _error_text(response)
        text = f"{path}: {status}{f' {code}' if code else ''}: {message}".rstrip(": ")
        if status == 401:
            raise TokenRefused(f"the server refused the token ({text}); " + CHECK_TOKEN)
        if status == 403:
            raise FatalError(f"the token may not act for this vehicle ({text})")
        if status == 404 or (status == 409 and code == "instance_finished"):
            raise SessionLost(text)
        if status in (413, 422):
            log.error("the server refused a request as invalid: %s", text)
        if status == 422:
            raise Refused(text, refused_fields(_error_details(response)))
        raise RetryableError(text, _retry_after(response))

    async def start_instance(self, body: StartInstance) -> StartInstanceResult:
        return await self._call(
            "POST", "/upper/start_instance", StartInstanceResult, json=body.model_dump(mode="json")
        )

    async def finish_instance(self, instance_id: str) -> None:
        await self._call(
            "POST",
            "/upper/finish_instance",
            FinishInstanceResult,
            json={"instance_id": instance_id},
        )

    async def heartbeat(self, instance_id: str) -> HeartbeatResult:
        return await self._call(
            "POST", "/upper/heartbeat", HeartbeatResult, json={"instance_id": instance_id}
        )

    async def update_param(self, body: UpdateParam) -> UpdateParamResult:
        return await self._call(
            "POST",
            "/upper/update_param",
            UpdateParamResult,
            json=body.model_dump(mode="json", exclude_none=True),
        )

    async def get_control(self, instance_id: str, wait_s: float) -> GetControlResult:
        return await self._call(
            "GET",
            "/upper/get_control",
            GetControlResult,
            params={"instance_id": instance_id, "wait_s": wait_s},
            limit_s=CALL_TIMEOUT_S + wait_s,
        )

    async def update_fbmessage(self, body: UpdateFbMessage) -> UpdateFbMessageResult:
        return await self._call(
            "POST",
            "/upper/update_fbmessage",
            UpdateFbMessageResult,
            json=body.model_dump(mode="json", exclude_none=True),
        )

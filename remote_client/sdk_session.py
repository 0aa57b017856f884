"""The SDK's session with a server: one HTTP client, the token, a call and its refusal."""

from __future__ import annotations

from collections.abc import Sequence
from types import TracebackType
from typing import Any, Self

import httpx

Body = dict[str, Any]

__all__ = ["Body", "FleetApiError", "Session", "given"]


class FleetApiError(Exception):
    """The server refused a call: its HTTP status and the contract's error envelope, and
    when to try again (``retry_after_s``: its ``Retry-After`` on a 429 or a 503)."""

    def __init__(
        self,
        status: int,
        code: str,
        message: str,
        details: list[dict[str, Any]] | None = None,
        retry_after_s: float | None = None,
    ) -> None:
        super().__init__(f"{status} {code}: {message}")
        self.status = status
        self.code = code
        self.message = message
        self.details = details or []
        self.retry_after_s = retry_after_s

    @classmethod
    def of(cls, response: httpx.Response) -> FleetApiError:
        try:
            retry_after_s: float | None = float(response.headers["retry-after"])
        except (KeyError, ValueError):
            retry_after_s = None
        try:
            error = response.json()["error"]
            return cls(
                response.status_code,
                error["code"],
                error["message"],
                error.get("details"),
                retry_after_s,
            )
        except (ValueError, KeyError, TypeError):
            return cls(response.status_code, "http_error", response.text[:500], None, retry_after_s)


class Session:
    """One HTTP client to a server with a token: :meth:`call` any route of the contract."""

    def __init__(
        self,
        server: str,
        token: str,
        *,
        client: httpx.AsyncClient | None = None,
        timeout_s: float = 30.0,
    ) -> None:
        self.server = server.rstrip("/")
        #: The token calls carry; ``expires_in``: its life in seconds, from a login.
        self.token = token
        self.expires_in: int | None = None
        self._headers = {"Authorization": f"Bearer {token}"}
        self._own_client = client is None
        self._http = client or httpx.AsyncClient(base_url=self.server, timeout=timeout_s)

    @classmethod
    async def login(
        cls,
        server: str,
        username: str,
        password: str,
        *,
        client: httpx.AsyncClient | None = None,
        timeout_s: float = 30.0,
    ) -> Self:
        """A session of a user who has a password (``POST /auth/token``): the token lasts
        ``expires_in`` seconds (the server's ``FLEET_TOKEN_TTL_S``, 12 h by default), and
        :meth:`logout` ends it. A wrong password is :class:`FleetApiError` 401, too many
        tries 429."""
        http = client or httpx.AsyncClient(base_url=server.rstrip("/"), timeout=timeout_s)
        try:
            credentials = {"username": username, "password": password}
            response = await http.post("/auth/token", json=credentials)
        finally:
            if client is None:
                await http.aclose()
        if response.status_code >= 400:
            raise FleetApiError.of(response)
        answer = response.json()
        session = cls(server, answer["access_token"], client=client, timeout_s=timeout_s)
        session.expires_in = answer.get("expires_in")
        return session

    async def logout(self) -> bool:
        """``POST /auth/logout``: a session's token ends at once (True); an API token is
        left valid (False)."""
        answer = await self.call("POST", "/auth/logout")
        return bool(answer.get("ended"))

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        if self._own_client:
            await self._http.aclose()

    async def call(self, method: str, path: str, **kwargs: Any) -> Any:
        """Any route of the contract: its JSON answer, or :class:`FleetApiError`. A body
        JSON cannot carry (NaN, an infinity) is refused here as the server would: 422."""
        try:
            response = await self._http.request(method, path, headers=self._headers, **kwargs)
        except ValueError as exc:  # httpx's JSON encoder: "Out of range float values..."
            raise FleetApiError(422, "invalid", f"not sent: {exc}") from None
        if response.status_code >= 400:
            raise FleetApiError.of(response)
        return response.json()


#: One id (a vehicle, an instance, a topic, a name) or several: a plain string is one.
OneOrMany = str | Sequence[str]


def listed(value: OneOrMany) -> list[str]:
    """``value`` as a list: a string is one id, never its characters."""
    return [value] if isinstance(value, str) else list(value)


def given(**fields: Any) -> Body:
    """The fields that are set (a command's optional ``args`` left out when ``None``)."""
    return {k: v for k, v in fields.items() if v is not None}

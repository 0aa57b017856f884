"""Changes made durable before they are answered, as ASGI middleware.

An operator's or an administrator's change (a ``POST``, ``PUT``, ``PATCH`` or
``DELETE`` outside ``/upper/``) is written to the store's journal, fsynced,
before its answer starts: on the embedded store a write is otherwise durable
only at the next flush (every few seconds), and an answer a crash then forgets
is a command the operator was told was taken, a zone that vanishes, a revoked
token that comes back. The writes of all the requests answered at one moment
share one append (:meth:`~server.storage.base.Store.make_durable`). On MongoDB
an acknowledged write is durable already: nothing is done. A vehicle's own
calls are left as they are: its samples have their own durable mark
(``durable_through_seq``), and its acks are made durable by the command service.
A journal that cannot be written now (a full disk) is logged and the answer goes
out all the same: the change is made, and durable at the first flush that works.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

CHANGES = frozenset({"POST", "PUT", "PATCH", "DELETE"})


class DurableAnswers:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            scope["type"] != "http"
            or scope["method"] not in CHANGES
            or scope["path"].startswith("/upper/")
        ):
            await self.app(scope, receive, send)
            return
        state = scope["app"].state

        async def send_durable(message: Message) -> None:
            if message["type"] == "http.response.start":
                services = getattr(state, "services", None)
                if services is not None:
                    await services.store.make_durable()
            await send(message)

        await self.app(scope, receive, send_durable)

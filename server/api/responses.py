"""JSON answers that never fail on a value JSON cannot hold.

:class:`SafeJSONResponse` is orjson, and when orjson refuses a value (an
integer past 64 bits, a lone surrogate, a key that is not a string: data
stored by an older version), the same value made safe by
:func:`fleet_protocol.served.json_safe` (integers past 64 bits as strings,
NaN and Infinity as null, lone surrogates as U+FFFD, keys as strings). What
the wire models accept today never needs it. The error envelope and the
routes that build their ``JSONResponse`` themselves use it; routes with a
response model are serialised by pydantic, whose free-form output fields
escape the same way (``fleet_protocol.served.ServedObject``).

:class:`ModelResponse` is an answer written straight from its pydantic model.
FastAPI validates and re-serialises whatever a route returns; the vehicles'
hot routes (called by every vehicle, several times a second) build their
answer model themselves, so they hand FastAPI a finished response instead.
The route keeps ``response_model`` for the OpenAPI schema.
"""

from __future__ import annotations

from typing import Any

import orjson
from pydantic import BaseModel
from pydantic_core import PydanticSerializationError
from starlette.responses import JSONResponse, Response

from fleet_protocol.served import safe_dumps

__all__ = ["ModelResponse", "SafeJSONResponse", "safe_json_bytes"]


def safe_json_bytes(content: Any) -> bytes:
    try:
        return orjson.dumps(content)
    except TypeError:  # orjson.JSONEncodeError is one
        return safe_dumps(content).encode()


class SafeJSONResponse(JSONResponse):
    def render(self, content: Any) -> bytes:
        return safe_json_bytes(content)


class ModelResponse(Response):
    media_type = "application/json"

    def render(self, content: Any) -> bytes:
        if isinstance(content, BaseModel):
            try:
                return content.model_dump_json().encode()
            except PydanticSerializationError:
                return safe_dumps(content.model_dump()).encode()
        return bytes(super().render(content))

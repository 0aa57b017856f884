"""An answer written straight from its pydantic model.

FastAPI validates and re-serialises whatever a route returns; the vehicles'
hot routes (called by every vehicle, several times a second) build their
answer model themselves, so they hand FastAPI a finished response instead.
The route keeps ``response_model`` for the OpenAPI schema.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel
from starlette.responses import Response


class ModelResponse(Response):
    media_type = "application/json"

    def render(self, content: Any) -> bytes:
        if isinstance(content, BaseModel):
            return content.model_dump_json().encode()
        return bytes(super().render(content))

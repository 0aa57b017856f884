"""The OpenAPI document says every error a route may answer, in the contract's envelope.

FastAPI documents a route's success and its own 422 shape; this adds, to every
operation, the statuses the error handler may send (``{"error": {"code",
"message", "details"}}``) and replaces the 422 schema with the envelope the
server really sends, so that a client (or a fuzzer checking the answers against
the document) finds each status and body it can get.
"""

from __future__ import annotations

from typing import Any

from fleet_protocol import ErrorEnvelope

#: Statuses every route may answer with the envelope, and what each means.
ERROR_STATUSES = {
    "400": "Bad request (a body that is not what the route reads)",
    "401": "No token, or one that is not valid (unknown, revoked, expired)",
    "403": "The caller may see this but its role may not do it",
    "404": "Not found, or not the caller's to see",
    "409": "Conflicts with the state (control not held, exists already, finished)",
    "413": "Body over FLEET_MAX_BODY_BYTES",
    "415": "A body sent with a Content-Encoding (the server reads bodies uncompressed)",
    "422": "Invalid input; details names each field",
    "429": "Rate limited; see Retry-After",
    "503": "The store or the server is not ready; see Retry-After",
}
_REF = {"$ref": "#/components/schemas/ErrorEnvelope"}
#: The operations any caller may make without a token (API.md, "Auth").
OPEN_PATHS = frozenset({"/healthz", "/readyz", "/metrics", "/auth/token"})
_BEARER = {
    "type": "http",
    "scheme": "bearer",
    "description": "an API token (fct_...: printed by a fresh server, or made by an admin) "
    "or a session's access_token from POST /auth/token",
}


def document_errors(schema: dict[str, Any]) -> dict[str, Any]:
    """``schema`` (an OpenAPI document) with the error answers on every operation."""
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components["ErrorEnvelope"] = ErrorEnvelope.model_json_schema(
        ref_template="#/components/schemas/{model}"
    )
    for name, sub in components["ErrorEnvelope"].pop("$defs", {}).items():
        components.setdefault(name, sub)
    schema["components"].setdefault("securitySchemes", {})["bearer"] = _BEARER
    for path, item in schema.get("paths", {}).items():
        for operation in item.values():
            if not isinstance(operation, dict) or "responses" not in operation:
                continue
            operation["security"] = [] if path in OPEN_PATHS else [{"bearer": []}]
            responses = operation["responses"]
            for status, description in ERROR_STATUSES.items():
                responses[status] = {
                    "description": description,
                    "content": {"application/json": {"schema": _REF}},
                }
    for unused in ("HTTPValidationError", "ValidationError"):
        components.pop(unused, None)
    return schema

"""Every name or note a person types for others to read keeps to one rule (``screen_rule``
in ``fleet_protocol.text``): no control characters, nor characters that reorder the text."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import BaseModel, ValidationError

from fleet_protocol import (
    CreateObstacle,
    CreateVehicle,
    CreateZone,
    DenyControl,
    PatchZone,
    StartInstance,
)
from fleet_protocol.ws import StartInstanceOp

SQUARE = {"type": "Polygon", "coordinates": [[[0, 0], [0, 1], [1, 1], [1, 0], [0, 0]]]}

#: Each model a person's text comes in by, a valid body, and the field read on screens.
SHOWN: list[tuple[type[BaseModel], dict[str, Any], str]] = [
    (CreateVehicle, {"vehicle_id": "v-1"}, "name"),
    (CreateVehicle, {"vehicle_id": "v-1"}, "vehicle_type"),
    (StartInstance, {"vehicle_id": "v-1"}, "name"),
    (StartInstance, {"vehicle_id": "v-1"}, "vehicle_type"),
    (StartInstanceOp, {"op": "start_instance", "vehicle_id": "v-1"}, "name"),
    (CreateObstacle, {"polygon": SQUARE}, "name"),
    (CreateZone, {"kind": "no_go", "polygon": SQUARE}, "name"),
    (PatchZone, {}, "name"),
    (DenyControl, {"instance_id": "i-1", "user": "op-1"}, "reason"),
]

BAD = [
    "z\x1b[2Jx",
    "a\x00b",
    "two\nlines",
    "tab\there",
    "del\x7f",
    "c1\x9bx",
    "ab\u202ec",
    "x\u2066y",
    # line breaks that are no control characters; marks that set a direction
    "Good\u2028Name",
    "Good\u2029Name",
    "a\u200eb",
    "a\u200fb",
    "a\u061cb",
    # characters a screen does not show: two names that read alike would differ by one
    "a\u200bb",
    "\ufeffab",
    "a\u00adb",
    "a\u180eb",
    "a\u2060b",
    "a\U000e0001b",
]

#: Invisible joiners that scripts and emoji need are kept.
PERSIAN = "\u0645\u06cc\u200c\u062e\u0648\u0627\u0647\u0645"  # a non-joiner inside
KEPT = [PERSIAN, "🧑\u200d🚀", "नमस्ते", "Ålesund — Pier 3"]


@pytest.mark.parametrize("text", KEPT)
def test_joiners_scripts_need_are_taken(text: str) -> None:
    assert CreateVehicle.model_validate({"vehicle_id": "v-1", "name": text}).name == text


@pytest.mark.parametrize(("model", "body", "field"), SHOWN)
def test_each_shown_field_takes_plain_text(
    model: type[BaseModel], body: dict[str, Any], field: str
) -> None:
    parsed = model.model_validate({**body, field: "Pier 3 — Ålesund"})
    assert getattr(parsed, field) == "Pier 3 — Ålesund"


@pytest.mark.parametrize("text", BAD)
@pytest.mark.parametrize(("model", "body", "field"), SHOWN)
def test_each_shown_field_refuses_control_and_reordering_characters(
    model: type[BaseModel], body: dict[str, Any], field: str, text: str
) -> None:
    with pytest.raises(ValidationError) as caught:
        model.model_validate({**body, field: text})
    (error,) = caught.value.errors()
    assert error["loc"] == (field,)
    assert "is shown on screens" in error["msg"]


def test_a_terminal_is_given_the_unseen_characters_escaped() -> None:
    from remote_client.output import shown

    assert shown("Good\u2028Name\u200f\u200b\U000e0001\x1b") == (
        "Good\\u2028Name\\u200f\\u200b\\U000e0001\\x1b"
    )
    assert shown("🧑\u200d🚀 نمس") == "🧑\u200d🚀 نمس"

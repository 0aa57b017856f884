"""``SampleDoc``: a sample read as a plain dict, under the very rules of ``Sample``."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import pytest
from pydantic import TypeAdapter, ValidationError

from fleet_protocol import Sample, UpdateParam, UpdateParamDocs
from fleet_protocol.common import SampleDoc

AS_MODELS = TypeAdapter(list[Sample])
AS_DOCS = TypeAdapter(list[SampleDoc])

GOOD = {"seq": 7, "ts": "2026-11-27T06:00:00.250Z", "lat": 43.9, "lon": 15.4}
CASES: list[Any] = [
    [GOOD],
    [{**GOOD, "depth_m": None, "battery_pct": 80.5, "data": None, "colour": "red"}],
    [{**GOOD, "ts": "2026-11-27T08:00:00+02:00", "data": {"rpm": [1, 2], "ok": True}}],
    [{**GOOD, "heading_deg": 360.0, "speed_mps": 0.0, "depth_m": -50.0}],
    [1, "x", None],
    [{**GOOD, "seq": 0, "lat": 91.0, "lon": -180.5}],
    [{**GOOD, "seq": True, "ts": "2100-01-01T00:00:00Z", "speed_mps": -1.0}],
    [{**GOOD, "seq": 1.5, "heading_deg": "90", "battery_pct": 100.5}],
    [{**GOOD, "data": {"$where": 1}}, {**GOOD, "data": [1]}, {**GOOD, "data": {"a.b": 1}}],
    [{"seq": 3}],
    [{**GOOD, "ts": "yesterday", "lat": 1e400}],
]


def _errors(read: Callable[[str], Any], text: str) -> list[tuple[Any, ...]] | None:
    """Each error's field, kind and message (the envelope's field and message come from
    them); a value that is no object is "not a model" to one, "not a dict" to the other."""
    try:
        read(text)
    except ValidationError as exc:
        kinds = {"model_type": "dict_type"}
        return [(e["loc"], kinds.get(e["type"], e["type"]), e["msg"]) for e in exc.errors()]
    return None


def test_the_dict_form_has_the_models_fields_and_the_same_required_ones() -> None:
    assert list(SampleDoc.__annotations__) == list(Sample.model_fields)
    required = {name for name, f in Sample.model_fields.items() if f.is_required()}
    assert set(SampleDoc.__required_keys__) == required


@pytest.mark.parametrize("case", CASES, ids=range(len(CASES)))
def test_a_sample_read_as_a_dict_passes_and_fails_as_the_model_does(case: Any) -> None:
    text = json.dumps(case)
    refused = _errors(AS_MODELS.validate_json, text)
    assert _errors(AS_DOCS.validate_json, text) == refused  # the same fields, types and messages
    if refused is None:
        docs = AS_DOCS.validate_json(text)
        models = AS_MODELS.validate_json(text)
        # Less its nulls, each dict is the model's stored form: unknown fields are ignored.
        assert [{k: v for k, v in d.items() if v is not None} for d in docs] == [
            m.model_dump(exclude_none=True) for m in models
        ]


def test_update_param_read_with_dict_samples_keeps_every_other_field_and_bound() -> None:
    assert set(UpdateParamDocs.model_fields) == set(UpdateParam.model_fields)
    body = {"instance_id": "i-1", "params": {"mode": "auto"}, "samples": [GOOD], "rtt_s": 0.2}
    read = UpdateParamDocs.model_validate_json(json.dumps(body))
    assert read.samples == [{**GOOD, "ts": Sample.model_validate(GOOD).ts}]
    assert (read.params, read.rtt_s) == ({"mode": "auto"}, 0.2)
    too_many = json.dumps({**body, "samples": [GOOD] * 5001})
    refused = _errors(UpdateParamDocs.model_validate_json, too_many)
    assert refused is not None and refused == _errors(UpdateParam.model_validate_json, too_many)

"""Values JSON or the store cannot hold stop at the wire models, with the path of the bad
value; what was stored before a rule existed is still encoded (escaped) on the way out."""

from __future__ import annotations

import json
import math
import types
from datetime import UTC, datetime
from typing import Annotated, Any, Union, get_args, get_origin

import pytest
from pydantic import AfterValidator, BaseModel, BeforeValidator, ValidationError
from pydantic.fields import FieldInfo

import fleet_protocol
from fleet_protocol import (
    MAX_INT,
    MAX_JSON_DEPTH,
    MAX_KEY_CHARS,
    MAX_PARAMS,
    MAX_SAMPLE_DATA_BYTES,
    MIN_INT,
    FailsafePolicy,
    Sample,
    StartInstance,
    SubmitControl,
    UpdateParam,
)
from fleet_protocol.errors import ErrorBody, ErrorEnvelope, FieldError
from fleet_protocol.served import json_safe, safe_dumps
from fleet_protocol.text import check_text
from fleet_protocol.topics import validate_topic
from fleet_protocol.values import json_problem
from fleet_protocol.ws import EventPush, PublishOp
from fleet_protocol.ws_frames import FrameError, field_errors, parse_client_op, parse_vehicle_op
from fleet_protocol.ws_pushes import _Push

TS = "2026-11-22T10:00:00.000Z"


def sample(seq: int = 1, **extra: Any) -> dict[str, Any]:
    return {"seq": seq, "ts": TS, "lat": 43.94, "lon": 15.44, **extra}


def refusal(model: type[BaseModel], value: Any) -> list[FieldError]:
    """The fields and messages of the refusal (python mode, as FastAPI validates a body)."""
    with pytest.raises(ValidationError) as caught:
        model.model_validate(value)
    return field_errors(caught.value)


def refused_field(model: type[BaseModel], value: Any) -> str:
    errors = refusal(model, value)
    assert len(errors) == 1, errors
    return errors[0].field


def data_field(data: Any, seq_index: int = 0) -> str:
    samples = [sample(i + 1) for i in range(seq_index)] + [sample(seq_index + 1, data=data)]
    return refused_field(UpdateParam, {"instance_id": "i-1", "samples": samples})


# -- integers ----------------------------------------------------------------


def test_integers_within_signed_64_bit_are_accepted_at_both_ends() -> None:
    body = UpdateParam.model_validate(
        {"instance_id": "i", "samples": [sample(data={"hi": MAX_INT, "lo": MIN_INT})]}
    )
    assert body.samples[0].data == {"hi": 2**63 - 1, "lo": -(2**63)}


@pytest.mark.parametrize("value", [2**63, 2**64, -(2**63) - 1, 10**30])
def test_an_integer_past_64_bits_is_refused_naming_it(value: int) -> None:
    assert data_field({"big": value}) == "samples.0.data.big"


def test_the_path_leads_into_nested_values() -> None:
    data = {"reading": [1, 2, {"ok": True}], "deep": {"list": [0, [5, 2**64]]}}
    assert data_field(data, seq_index=3) == "samples.3.data.deep.list.1.1"
    assert data_field({"reading": [2**70]}) == "samples.0.data.reading.0"


# -- floats ------------------------------------------------------------------


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_nan_and_infinity_are_refused_in_free_form_data(value: float) -> None:
    assert data_field({"x": value}) == "samples.0.data.x"
    assert data_field({"x": [1.5, value]}) == "samples.0.data.x.1"


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity"])
def test_nan_tokens_in_json_text_are_refused_on_the_socket(token: str) -> None:
    text = (
        '{"op": "update_param", "id": "u1", "instance_id": "i",'
        f' "samples": [{{"seq": 1, "ts": "{TS}", "lat": 1, "lon": 2, "data": {{"x": {token}}}}}]}}'
    )
    reply = socket_failure(parse_vehicle_op, text)
    assert reply["op"] == "ack" and reply["id"] == "u1" and reply["ok"] is False
    assert [d["field"] for d in reply["error"]["details"]] == ["samples.0.data.x"]


def test_every_float_field_is_finite() -> None:
    # FailsafePolicy.after_s names no allow_inf_nan itself: the WireModel config refuses it.
    assert refused_field(FailsafePolicy, {"after_s": math.nan}) == "after_s"
    assert refused_field(FailsafePolicy, {"after_s": math.inf}) == "after_s"
    assert refused_field(Sample, sample(depth_m=-math.inf)) == "depth_m"


# -- strings -----------------------------------------------------------------


def test_a_lone_surrogate_in_a_value_is_refused() -> None:
    assert data_field({"note": "ok \ud800"}) == "samples.0.data.note"
    assert data_field({"notes": ["fine", "\udfff"]}) == "samples.0.data.notes.1"


def test_surrogate_pairs_and_other_unicode_are_fine() -> None:
    body = UpdateParam.model_validate(
        {"instance_id": "i", "samples": [sample(data={"fish": "🐟 Æøå", "ключ": "значение"})]}
    )
    assert body.samples[0].data == {"fish": "🐟 Æøå", "ключ": "значение"}


def test_a_lone_surrogate_in_a_key_is_refused_and_shown_escaped() -> None:
    errors = refusal(UpdateParam, {"instance_id": "i", "samples": [sample(data={"a\ud800": 1})]})
    assert [e.field for e in errors] == ["samples.0.data.a\ufffd"]
    json.dumps(errors[0].model_dump(), ensure_ascii=False).encode()  # UTF-8 can hold it


def test_a_lone_surrogate_in_a_plain_str_field_is_refused() -> None:
    assert refused_field(StartInstance, {"vehicle_id": "usv-1", "name": "boat \ud800"}) == "name"
    body = {"instance_ids": ["i-1", "i-\udc00"], "command": {"type": "stop"}}
    assert refused_field(SubmitControl, body) == "instance_ids.1"


def test_a_lone_surrogate_on_the_socket_names_the_field() -> None:
    # The socket's JSON parser refuses "\ud800" outright; the reply still names the field.
    text = json.dumps(
        {"op": "update_param", "id": "u2", "instance_id": "i", "samples": [sample(data={})]}
    ).replace('"data": {}', '"data": {"x": "\\ud800"}')
    reply = socket_failure(parse_vehicle_op, text)
    assert reply["id"] == "u2" and reply["ok"] is False
    assert [d["field"] for d in reply["error"]["details"]] == ["samples.0.data.x"]
    no_id = socket_failure(parse_vehicle_op, text.replace('"id": "u2", ', ""))
    assert no_id["op"] == "error"
    assert [d["field"] for d in no_id["error"]["details"]] == ["samples.0.data.x"]


def test_an_op_id_with_a_lone_surrogate_is_answered_with_an_error_push() -> None:
    text = '{"op": "heartbeat", "id": "\\ud800", "instance_id": 5}'
    reply = socket_failure(parse_vehicle_op, text)
    assert reply["op"] == "error" and reply["error"]["code"] == "invalid"


# -- keys --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("key", "shown", "why"),
    [
        ("$where", "$where", "start with '$'"),
        ("a.b", "a.b", "'.'"),
        ("a\x00b", "a\x00b", "NUL"),
        ("k" * (MAX_KEY_CHARS + 1), "k" * MAX_KEY_CHARS + "…", f"{MAX_KEY_CHARS} characters"),
    ],
)
def test_keys_the_store_cannot_hold_are_refused(key: str, shown: str, why: str) -> None:
    errors = refusal(UpdateParam, {"instance_id": "i", "samples": [sample(data={"x": {key: 1}})]})
    assert [e.field for e in errors] == [f"samples.0.data.x.{shown}"]
    assert why in errors[0].message


def test_keys_in_params_are_checked_too() -> None:
    assert refused_field(UpdateParam, {"instance_id": "i", "params": {"$set": 1}}) == "params.$set"
    body = {"vehicle_id": "usv-1", "params": {"sensors": {"ctd.temp": 1}}}
    assert refused_field(StartInstance, body) == "params.sensors.ctd.temp"


def test_a_key_that_is_not_a_string_is_refused_in_python_values() -> None:
    assert json_problem({"a": {1: "x"}}) == (("a", "1"), "an object's keys are strings")


def test_keys_of_the_right_shape_pass() -> None:
    keys = {"": 1, "k" * MAX_KEY_CHARS: 2, "a$b": 3, "/ros/topic": 4, "ünïcode": 5}
    assert UpdateParam.model_validate({"instance_id": "i", "params": keys}).params == keys


# -- depth -------------------------------------------------------------------


def nested(levels: int) -> Any:
    """``levels`` objects and arrays inside each other."""
    value: Any = 1
    for level in range(levels):
        value = {"a": value} if level % 2 else [value]
    return value


def test_nesting_up_to_the_limit_is_accepted_and_one_more_is_refused() -> None:
    ok = {"v": nested(MAX_JSON_DEPTH - 1)}  # data itself is the first level
    assert UpdateParam.model_validate({"instance_id": "i", "samples": [sample(data=ok)]})
    field = data_field({"v": nested(MAX_JSON_DEPTH)})
    assert field.startswith("samples.0.data.v.")
    errors = refusal(UpdateParam, {"instance_id": "i", "params": {"v": nested(200)}})
    assert f"deeper than {MAX_JSON_DEPTH}" in errors[0].message


def test_deep_nesting_in_publish_data_is_refused() -> None:
    frame = json.dumps({"op": "publish", "id": "p", "topic": "user/u/x", "data": nested(40)})
    reply = socket_failure(parse_client_op, frame)
    assert reply["ok"] is False
    assert reply["error"]["details"][0]["field"].startswith("data.")


# -- timestamps --------------------------------------------------------------


@pytest.mark.parametrize(
    "ts",
    [
        "0001-01-01T00:00:00Z",
        "1969-12-31T23:59:59.999Z",
        "2100-01-01T00:00:00.001Z",
        "2100-01-01T00:00:00Z",  # the range's end, excluded: the widest window's to
        "9999-12-31T23:59:59-01:00",  # past year 9999 once in UTC
        "0001-01-01T00:30:00+01:00",  # before year 1 once in UTC
    ],
)
def test_a_timestamp_out_of_range_is_refused_naming_it(ts: str) -> None:
    body = {"instance_id": "i", "samples": [sample(), sample(2, ts=ts)]}
    errors = refusal(UpdateParam, body)
    assert [e.field for e in errors] == ["samples.1.ts"]
    assert "1970-01-01T00:00:00.000Z" in errors[0].message


@pytest.mark.parametrize(
    ("ts", "utc"),
    [
        ("1970-01-01T00:00:00Z", datetime(1970, 1, 1, tzinfo=UTC)),  # no GPS fix: the epoch
        ("2099-12-31T23:59:59.999Z", datetime(2099, 12, 31, 23, 59, 59, 999000, tzinfo=UTC)),
        ("1970-01-01T01:00:00+01:00", datetime(1970, 1, 1, tzinfo=UTC)),
        ("2026-11-22T10:00:00", datetime(2026, 11, 22, 10, tzinfo=UTC)),  # naive: UTC
    ],
)
def test_timestamps_at_the_ends_of_the_range_are_accepted(ts: str, utc: datetime) -> None:
    assert Sample.model_validate(sample(ts=ts)).ts == utc


# -- bounds that were there before -------------------------------------------


def test_sample_data_and_params_keep_their_size_bounds() -> None:
    big = {"blob": "x" * MAX_SAMPLE_DATA_BYTES}
    errors = refusal(UpdateParam, {"instance_id": "i", "samples": [sample(data=big)]})
    assert [e.field for e in errors] == ["samples.0.data"]
    assert f"at most {MAX_SAMPLE_DATA_BYTES}" in errors[0].message
    many = {f"p{i}": i for i in range(MAX_PARAMS + 1)}
    assert refused_field(UpdateParam, {"instance_id": "i", "params": many}) == "params"
    assert refused_field(UpdateParam, {"instance_id": "i", "params": [1]}) == "params"


def test_valid_values_come_through_unchanged_in_both_modes() -> None:
    data = {"t": 14.2, "n": -3, "ok": True, "none": None, "list": [1, "a", [2.5]], "o": {"k": "v"}}
    body = {"instance_id": "i", "params": {"p": data}, "samples": [sample(data=data)]}
    python = UpdateParam.model_validate(body)
    text = UpdateParam.model_validate_json(json.dumps(body))
    for parsed in (python, text):
        assert parsed.samples[0].data == data and parsed.params == {"p": data}
    op = parse_client_op(json.dumps({"op": "publish", "topic": "user/u/x", "data": data}))
    assert isinstance(op, PublishOp) and op.data == data
    assert parse_client_op('{"op": "publish", "topic": "user/u/x", "data": null}').data is None


# -- every str field is checked ------------------------------------------------

_CHECKED_BY = {check_text, validate_topic}


def _str_checked(metadata: list[Any]) -> bool:
    for item in metadata:
        if isinstance(item, AfterValidator | BeforeValidator) and item.func in _CHECKED_BY:
            return True
        if getattr(item, "pattern", None):  # a pattern of ASCII characters (identifiers)
            return True
        if isinstance(item, FieldInfo) and _str_checked(item.metadata):
            return True
    return False


def _unchecked_str(annotation: Any, metadata: list[Any]) -> bool:
    if annotation is str:
        return not _str_checked(metadata)
    origin = get_origin(annotation)
    if origin is Annotated:
        inner, *more = get_args(annotation)
        return _unchecked_str(inner, [*more, *metadata])
    if origin in (Union, types.UnionType):
        return any(_unchecked_str(arg, metadata) for arg in get_args(annotation))
    if origin in (list, tuple):
        return any(_unchecked_str(arg, []) for arg in get_args(annotation) if arg is not ...)
    if origin is dict:  # the values; free-form keys are JsonObject's (tested above)
        return _unchecked_str(get_args(annotation)[1], [])
    return False


def _wire_models() -> list[type[BaseModel]]:
    found = set()
    for name in dir(fleet_protocol):
        obj = getattr(fleet_protocol, name)
        if isinstance(obj, type) and issubclass(obj, BaseModel):
            found.add(obj)
    found |= set(_Push.__subclasses__())
    return sorted(found - {ErrorBody, ErrorEnvelope, FieldError}, key=lambda m: m.__name__)


def test_every_str_field_of_every_wire_model_refuses_lone_surrogates() -> None:
    models = _wire_models()
    assert len(models) > 40
    unchecked = [
        f"{model.__name__}.{name}"
        for model in models
        for name, info in model.model_fields.items()
        if _unchecked_str(info.annotation, list(info.metadata))
    ]
    assert unchecked == []


# -- the way out: stored values that break a rule are escaped, never refused --


def strict_loads(text: str) -> Any:
    """JSON as a strict reader takes it: no NaN tokens, UTF-8 encodable text."""

    def no_constants(token: str) -> Any:
        raise AssertionError(f"{token} is not JSON")

    text.encode("utf-8")  # a lone surrogate would fail here
    return json.loads(text, parse_constant=no_constants)


def test_json_safe_escapes_what_json_cannot_hold() -> None:
    stored = {
        "big": 2**64,
        "neg": -(2**70),
        "edge": MAX_INT,
        "nan": math.nan,
        "inf": [math.inf, 1.5],
        "text": "a\ud800b",
        "k\udfff": 1,
        7: "seven",
        "when": datetime(2026, 11, 22, 10, tzinfo=UTC),
    }
    decoded = strict_loads(safe_dumps(stored))
    assert decoded == {
        "big": str(2**64),
        "neg": str(-(2**70)),
        "edge": MAX_INT,
        "nan": None,
        "inf": [None, 1.5],
        "text": "a\ufffdb",
        "k\ufffd": 1,
        "7": "seven",
        "when": "2026-11-22T10:00:00.000Z",
    }
    assert json_safe({"ok": [1, "x", None]}) == {"ok": [1, "x", None]}


def test_a_push_with_stored_data_json_cannot_hold_is_still_framed() -> None:
    push = EventPush(topic="vehicle/usv-1/telemetry", data={"s": "\ud800", "big": 2**64})
    assert strict_loads(push.frame())["data"] == {"s": "\ufffd", "big": str(2**64)}
    # The hot path is untouched: a clean push is pydantic's own JSON.
    clean = EventPush(topic="vehicle/usv-1/telemetry", data={"x": 1})
    assert clean.frame() == clean.model_dump_json()


def socket_failure(parse: Any, text: str) -> dict[str, Any]:
    with pytest.raises(FrameError) as caught:
        parse(text)
    return strict_loads(caught.value.reply().frame())  # type: ignore[no-any-return]

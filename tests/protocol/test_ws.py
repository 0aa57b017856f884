"""WebSocket ops and pushes: parsed once, failures turned into the contract's bodies."""

from __future__ import annotations

import json
from datetime import UTC, datetime

import pytest

from fleet_protocol import upper
from fleet_protocol.errors import ErrorBody
from fleet_protocol.media import MediaHeader, decode_media_frame, encode_media_frame
from fleet_protocol.ws import (
    AbortPush,
    AckPush,
    BatchOp,
    CommandPush,
    ControlPush,
    ErrorPush,
    EventPush,
    HeartbeatOp,
    LaggingPush,
    PublishOp,
    RegisterOp,
    RoutesPush,
    StartInstanceOp,
    SubscribeOp,
    UpdateParamOp,
)
from fleet_protocol.ws_frames import FrameError, PartialBatch, parse_client_op, parse_vehicle_op
from vehicle_client.transport.wire import parse_push

TS = "2026-11-22T10:00:00.123Z"


def frame(**fields: object) -> str:
    return json.dumps(fields)


def failure(parse, text: str | bytes) -> dict:
    with pytest.raises(FrameError) as caught:
        parse(text)
    return json.loads(caught.value.reply().frame())


def test_update_param_op_is_the_http_body_plus_op_and_id():
    op = parse_vehicle_op(
        frame(
            op="update_param",
            id="7",
            instance_id="i-1",
            params={"mode": "survey"},
            samples=[{"seq": 1, "ts": TS, "lat": 63.4, "lon": 10.4}],
        )
    )
    assert isinstance(op, UpdateParamOp)
    assert isinstance(op, upper.UpdateParam)
    assert op.id == "7"
    assert op.samples[0].seq == 1
    assert op.params == {"mode": "survey"}


@pytest.mark.parametrize(
    ("fields", "model"),
    [
        ({"op": "start_instance", "vehicle_id": "usv-1"}, StartInstanceOp),
        ({"op": "heartbeat", "instance_id": "i-1"}, HeartbeatOp),
        ({"op": "register", "topics": ["vehicle/usv-1/camera"]}, RegisterOp),
        ({"op": "subscribe", "topics": ["fleet"], "throttle_ms": 200}, SubscribeOp),
        ({"op": "publish", "topic": "vehicle/usv-1/sonar", "data": {"x": 1}}, PublishOp),
    ],
)
def test_each_vehicle_op_parses_to_its_model(fields, model):
    assert type(parse_vehicle_op(frame(**fields))) is model


def test_batch_holds_ops_each_with_its_own_id():
    op = parse_vehicle_op(
        frame(
            op="batch",
            id="b",
            ops=[
                {"op": "heartbeat", "id": "h1", "instance_id": "i-1"},
                {"op": "publish", "topic": "vehicle/usv-2/depth", "vehicle_id": "usv-2", "data": 3},
            ],
        )
    )
    assert isinstance(op, BatchOp)
    assert [type(inner) for inner in op.ops] == [HeartbeatOp, PublishOp]
    assert op.ops[0].id == "h1"
    assert op.ops[1].vehicle_id == "usv-2"


def test_a_batch_inside_a_batch_is_refused():
    body = failure(parse_vehicle_op, frame(op="batch", id="b", ops=[{"op": "batch", "ops": []}]))
    assert body["ok"] is False
    assert body["error"]["details"][0]["field"] == "ops.0.op"


def test_a_batch_with_some_bad_ops_keeps_the_good_ones_and_refuses_each_bad_one():
    good = {"op": "update_param", "id": "g", "instance_id": "i-1", "samples": []}
    bad_ts = {"op": "update_param", "id": "t", "instance_id": "i-1"}
    bad_ts["samples"] = [{"seq": 1, "ts": "soon", "lat": 1, "lon": 2}]
    bad_anonymous = {"op": "heartbeat", "instance_id": 5}
    hb = {"op": "heartbeat", "id": "h", "instance_id": "i-1"}
    with pytest.raises(PartialBatch) as caught:
        parse_vehicle_op(frame(op="batch", id="b", ops=[good, bad_ts, hb, bad_anonymous]))
    partial = caught.value
    assert [type(op) for op in partial.batch.ops] == [UpdateParamOp, HeartbeatOp]
    assert [op.id for op in partial.batch.ops] == ["g", "h"]
    assert partial.batch.id == "b"
    # The batch as sent: each bad op's refusal in its place, to be answered there.
    ids = [op.op_id if isinstance(op, FrameError) else op.id for op in partial.in_order]
    assert ids == ["g", "t", "h", None]
    assert [isinstance(op, FrameError) for op in partial.in_order] == [False, True, False, True]
    first, second = (json.loads(r.reply().frame()) for r in partial.refused)
    assert first["op"] == "ack" and first["id"] == "t" and first["ok"] is False
    assert first["error"]["details"][0]["field"] == "samples.0.ts"
    assert second["op"] == "error"  # no id: nothing to ack
    assert second["error"]["details"][0]["field"] == "instance_id"
    # As a frame error it is the whole batch's refusal, each field named within the batch.
    whole = json.loads(partial.reply().frame())
    assert whole["id"] == "b" and whole["ok"] is False
    fields = {d["field"] for d in whole["error"]["details"]}
    assert fields == {"ops.1.samples.0.ts", "ops.3.instance_id"}


def test_a_batch_with_no_good_op_or_a_bad_envelope_is_refused_whole():
    bad = {"op": "heartbeat", "id": "h", "instance_id": 5}
    with pytest.raises(PartialBatch) as caught:
        parse_vehicle_op(frame(op="batch", id="b", ops=[bad]))
    assert caught.value.batch.ops == []
    assert [r.op_id for r in caught.value.refused] == ["h"]
    for envelope in (
        frame(op="batch", id="b", ops="x"),
        frame(op="batch", id="b", ops=[]),
        frame(op="batch", id="b" * 100, ops=[bad]),
        frame(op="batch", id="b", ops=[{"op": "heartbeat", "instance_id": "i-1"}] * 257),
    ):
        with pytest.raises(FrameError) as whole:
            parse_vehicle_op(envelope)
        assert not isinstance(whole.value, PartialBatch), envelope[:60]


def test_client_socket_refuses_vehicle_ops():
    body = failure(parse_client_op, frame(op="heartbeat", id="h", instance_id="i-1"))
    assert body == {
        "op": "ack",
        "id": "h",
        "ok": False,
        "error": body["error"],
    }
    assert body["error"]["code"] == "invalid"
    assert "unknown op" in body["error"]["details"][0]["message"]


def test_client_subscribe_takes_a_null_throttle_as_none():
    op = parse_client_op(frame(op="subscribe", topics=["fleet"], throttle_ms=None))
    assert isinstance(op, SubscribeOp) and op.throttle_ms == 0


def test_client_subscribe_parses_with_throttle():
    op = parse_client_op(frame(op="subscribe", topics=["vehicle/usv-1/telemetry"], throttle_ms=50))
    assert isinstance(op, SubscribeOp)
    assert op.throttle_ms == 50


def test_failure_with_an_id_is_an_ack_naming_the_field():
    body = failure(
        parse_vehicle_op, frame(op="update_param", id="9", instance_id="i", samples=[{}])
    )
    assert body["op"] == "ack"
    assert body["id"] == "9"
    assert body["ok"] is False
    fields = {d["field"] for d in body["error"]["details"]}
    assert {"samples.0.seq", "samples.0.ts", "samples.0.lat", "samples.0.lon"} <= fields


def test_failure_without_an_id_is_an_error_push():
    body = failure(parse_vehicle_op, frame(op="subscribe", topics=["fleet/#"]))
    assert body["op"] == "error"
    assert body["error"]["code"] == "invalid"
    assert body["error"]["details"][0]["field"] == "topics.0"


def test_an_id_over_64_characters_is_refused_and_not_echoed():
    body = failure(parse_vehicle_op, frame(op="heartbeat", id="x" * 65, instance_id="i"))
    assert body["op"] == "error"
    assert body["error"]["details"][0]["field"] == "id"


@pytest.mark.parametrize("parse", [parse_vehicle_op, parse_client_op])
def test_a_null_id_is_refused_not_taken_for_no_id(parse):
    """``id`` is a string: ``null`` would run the op with no ack the sender waits for."""
    body = failure(parse, frame(op="subscribe", id=None, topics=["fleet"]))
    assert body["op"] == "error"
    assert body["error"]["details"][0]["field"] == "id"
    assert "leave it out" in body["error"]["details"][0]["message"]
    assert parse(frame(op="subscribe", topics=["fleet"])).id is None  # left out: fine


def test_an_abort_push_reads_back_and_is_never_dropped():
    push = AbortPush(instance_id="i-1", command_ids=["c-1", "c-2"])
    assert json.loads(push.frame()) == {
        "op": "abort", "instance_id": "i-1", "command_ids": ["c-1", "c-2"],
    }  # fmt: skip
    assert push.critical
    assert parse_push(push.frame()) == push


@pytest.mark.parametrize("text", ["not json", b"\xff\xfe", "[1, 2]", '"heartbeat"'])
def test_frames_that_are_not_objects_get_an_error_push(text):
    body = failure(parse_vehicle_op, text)
    assert body["op"] == "error"
    assert body["error"]["code"] == "invalid"


def test_missing_op_is_named():
    body = failure(parse_client_op, frame(id="1", topics=["fleet"]))
    assert body["error"]["details"] == [{"field": "op", "message": "the frame has no 'op'"}]


def test_ack_success_carries_the_http_answer_fields():
    result = upper.UpdateParamResult(
        accepted=2, duplicates=0, acked_through_seq=5, durable_through_seq=3
    )
    body = json.loads(AckPush.success("7", result).frame())
    assert body == {
        "op": "ack",
        "id": "7",
        "ok": True,
        "accepted": 2,
        "duplicates": 0,
        "acked_through_seq": 5,
        "durable_through_seq": 3,
        "server_time": None,  # optional: the server's own acks carry its time
    }


def test_ack_success_keeps_null_answer_fields_and_cannot_be_overridden():
    body = json.loads(AckPush.success("s", {"control": None, "ok": False, "op": "x"}).frame())
    assert body == {"op": "ack", "id": "s", "ok": True, "control": None}


def test_ack_failure_and_error_push_carry_the_error_body():
    error = ErrorBody(code="forbidden", message="not your vehicle")
    assert json.loads(AckPush.failure("1", error).frame())["error"]["code"] == "forbidden"
    assert json.loads(ErrorPush(error=error).frame()) == {
        "op": "error",
        "error": {"code": "forbidden", "message": "not your vehicle", "details": None},
    }


def make_command(type_: str = "stop") -> dict:
    return {
        "command_id": "c-1",
        "instance_id": "i-1",
        "type": type_,
        "args": {},
        "status": "queued",
        "issued_by": "alice",
        "issued_at": TS,
        "expires_at": TS,
    }


def test_command_push_is_the_command_object_and_stop_is_critical():
    stop = CommandPush.model_validate(make_command("stop"))
    body = json.loads(stop.frame())
    assert body["op"] == "command"
    assert body["command_id"] == "c-1"
    assert body["issued_at"] == TS
    assert stop.critical
    go = CommandPush.model_validate(make_command("go_to") | {"args": {"lat": 1, "lon": 2}})
    assert not go.critical


def test_event_push_omits_snapshot_unless_set():
    assert json.loads(EventPush(topic="fleet", data={"a": 1}).frame()) == {
        "op": "event",
        "topic": "fleet",
        "data": {"a": 1},
    }
    snap = json.loads(EventPush(topic="fleet", data=None, snapshot=True).frame())
    assert snap["snapshot"] is True
    assert "data" in snap


def test_an_event_framed_again_is_what_came():
    """A gateway rebuilds each event from above for its units: nothing of it is lost, a
    field this version does not know included (``source`` was lost)."""
    came = {
        "op": "event",
        "topic": "user/ana/src/g1",
        "data": {"x": 2, "replayed": True},
        "source": "user:ana",
        "ts": "2026-11-22T10:00:00.123Z",
        "snapshot": True,
        "newer": [1],
    }
    assert json.loads(EventPush.model_validate_json(json.dumps(came)).frame()) == came


def test_other_pushes_serialise_with_their_op():
    assert json.loads(LaggingPush(dropped=3).frame()) == {"op": "lagging", "dropped": 3}
    control = json.loads(ControlPush(instance_id="i-1").frame())
    assert control == {"op": "control", "instance_id": "i-1", "control": None}
    routes = json.loads(RoutesPush(unit="usv-1", produces={"vehicle/usv-1/camera": []}).frame())
    assert routes["op"] == "routes"
    assert routes["produces"] == {"vehicle/usv-1/camera": []}


def test_media_frame_round_trip():
    header = MediaHeader(
        topic="vehicle/usv-1/camera",
        ts=datetime(2026, 11, 22, 10, tzinfo=UTC),
        content_type="image/jpeg",
    )
    payload = bytes(range(256)) * 4 + b"\n\n"
    decoded_header, decoded_payload = decode_media_frame(encode_media_frame(header, payload))
    assert decoded_header == header
    assert decoded_payload == payload


@pytest.mark.parametrize(
    "data",
    [b"no newline here", b'{"topic": "bad topic", "ts": "x"}\n', b"x" * 2000 + b"\n"],
)
def test_bad_media_frames_raise_frame_error(data):
    with pytest.raises(FrameError) as caught:
        decode_media_frame(data)
    assert caught.value.reply().op == "error"

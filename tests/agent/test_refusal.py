"""What a refused ``update_param`` blames (pure): the samples it names, its parameters."""

from __future__ import annotations

from vehicle_client.errors import refusal_of

BATCH = [{"seq": 11}, {"seq": 12}, {"seq": 13}]


def test_the_samples_named_are_blamed_by_their_seq() -> None:
    refusal = refusal_of([("samples.2.lat", "too big"), ("samples.0.ts", "bad")], BATCH)
    assert refusal.seqs == [11, 13]
    assert not refusal.params
    assert refusal.reason == "samples.2.lat: too big; samples.0.ts: bad"


def test_parameters_are_blamed_apart_from_the_samples() -> None:
    refusal = refusal_of([("params.mode", "not JSON")], BATCH)
    assert refusal.seqs == [] and refusal.params


def test_a_field_past_the_batch_or_of_another_kind_blames_nothing() -> None:
    refusal = refusal_of([("samples.7.lat", "x"), ("instance_id", "y"), ("samples", "z")], BATCH)
    assert refusal.seqs == [] and not refusal.params


def test_the_reason_names_the_first_five_fields() -> None:
    errors = [(f"samples.{i}.lat", "bad") for i in range(3)] + [("a", "1"), ("b", "2"), ("c", "3")]
    assert refusal_of(errors, BATCH).reason.count(";") == 4

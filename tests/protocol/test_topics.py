"""Topic grammar and the media convention."""

from __future__ import annotations

import pytest
from pydantic import TypeAdapter, ValidationError

from fleet_protocol.topics import (
    Topic,
    is_media_topic,
    split_topic,
    topic_owner,
    validate_topic,
    vehicle_topic,
)


@pytest.mark.parametrize(
    "topic",
    [
        "fleet",
        "vehicle/usv-1/telemetry",
        "user/alice/seg_mask",
        "a/b/c/d/e/f/g/h",
        "x" * 128,
        "0/_/-",
    ],
)
def test_valid_topics(topic):
    assert validate_topic(topic) == topic


@pytest.mark.parametrize(
    ("topic", "why"),
    [
        ("", "not empty"),
        ("x" * 129, "at most 128"),
        ("a/b/c/d/e/f/g/h/i", "at most 8 segments"),
        ("vehicle//x", "empty segment"),
        ("/fleet", "empty segment"),
        ("fleet/", "empty segment"),
        ("vehicle/+/telemetry", "no wildcards"),
        ("vehicle/#", "no wildcards"),
        ("vehicle/*/x", "no wildcards"),
        ("Vehicle/usv-1/x", "a-z"),
        ("vehicle/usv 1/x", "a-z"),
        ("vehicle/usv.1/x", "a-z"),
    ],
)
def test_invalid_topics_say_why(topic, why):
    with pytest.raises(ValueError, match=why):
        validate_topic(topic)


def test_topic_type_validates_in_models():
    adapter = TypeAdapter(Topic)
    assert adapter.validate_python("fleet") == "fleet"
    with pytest.raises(ValidationError):
        adapter.validate_python("fleet/#")
    with pytest.raises(ValidationError):
        adapter.validate_python(7)


def test_split_and_owner():
    assert split_topic("vehicle/usv-1/camera/front") == ["vehicle", "usv-1", "camera", "front"]
    assert topic_owner("vehicle/usv-1/camera") == ("vehicle", "usv-1")
    assert topic_owner("fleet") == ("fleet", None)


@pytest.mark.parametrize(
    ("topic", "media"),
    [
        ("vehicle/usv-1/camera", True),
        ("vehicle/usv-1/camera/front", True),
        ("vehicle/usv-1/sonar", True),
        ("user/worker/image/mask", True),
        ("vehicle/usv-1/telemetry", False),
        ("vehicle/camera/depth", False),  # a vehicle named "camera" is not media
        ("user/camera/result", False),
        ("fleet", False),
    ],
)
def test_media_topics(topic, media):
    assert is_media_topic(topic) is media


def test_vehicle_topic_builds_and_validates():
    assert vehicle_topic("usv-1", "telemetry") == "vehicle/usv-1/telemetry"
    with pytest.raises(ValueError):
        vehicle_topic("USV", "telemetry")

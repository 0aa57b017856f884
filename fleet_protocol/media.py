"""Binary frames on media topics: one JSON header line, a newline, then the bytes."""

from __future__ import annotations

from pydantic import Field, ValidationError

from fleet_protocol.common import Timestamp, WireModel
from fleet_protocol.errors import ErrorBody
from fleet_protocol.text import Text
from fleet_protocol.topics import Topic
from fleet_protocol.ws import MAX_MEDIA_HEADER_BYTES
from fleet_protocol.ws_frames import FrameError, error_body

__all__ = ["MediaHeader", "decode_media_frame", "encode_media_frame"]


class MediaHeader(WireModel):
    topic: Topic
    ts: Timestamp
    content_type: Text = Field(min_length=1, max_length=128)


def encode_media_frame(header: MediaHeader, payload: bytes) -> bytes:
    """A binary frame: the header as one JSON line, ``\\n``, then the bytes."""
    return header.model_dump_json().encode() + b"\n" + payload


def decode_media_frame(frame: bytes) -> tuple[MediaHeader, bytes]:
    """Header and payload of a binary frame, or :class:`FrameError`."""
    end = frame.find(b"\n", 0, MAX_MEDIA_HEADER_BYTES + 1)
    if end < 0:
        raise FrameError(
            ErrorBody(
                code="invalid",
                message="a binary frame starts with a JSON header line of at most"
                f" {MAX_MEDIA_HEADER_BYTES} bytes ending in a newline",
            )
        )
    try:
        header = MediaHeader.model_validate_json(frame[:end])
    except ValidationError as exc:
        raise FrameError(error_body(exc)) from None
    return header, frame[end + 1 :]

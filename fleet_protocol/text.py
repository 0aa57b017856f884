"""Strings on the wire: the checked ``str`` types, and text made safe to show.

A ``str`` field is :data:`Text`: no lone UTF-16 surrogate (U+D800..U+DFFF),
which neither UTF-8 nor BSON can hold, yet Python's ``json`` decodes
``"\\ud800"`` into one (pydantic's plain ``str`` lets it through). A name
people read on a console or a terminal is :data:`Label`: ``Text`` without
control characters, nor characters that reorder the text around them
(``docs/limits.md``); other text typed for people to read (a reason) is
:data:`Note`, under the same rule (:func:`screen_rule`).

The other way, text quoted in a message: :func:`shown_text` replaces lone
surrogates, :func:`escape_controls` shows control characters as escapes.

The free-form values (``JsonValue``, ``JsonObject``...) check their strings
and keys with the same rule: :mod:`fleet_protocol.values`.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Annotated

from pydantic import BeforeValidator
from pydantic_core import PydanticCustomError

__all__ = [
    "BIDI_CONTROLS",
    "INVISIBLES",
    "LINE_SEPARATORS",
    "SURROGATE",
    "UNSHOWN",
    "Label",
    "Note",
    "Text",
    "check_text",
    "escape_controls",
    "escape_unshown",
    "screen_rule",
    "shown_text",
]

#: A lone UTF-16 surrogate: what neither UTF-8 nor BSON can hold.
SURROGATE = re.compile("[\ud800-\udfff]")
#: Why a string with a lone surrogate is refused.
SURROGATE_MSG = "a string may not hold a lone UTF-16 surrogate (U+D800 to U+DFFF)"


def has_surrogate(text: str) -> bool:
    return not text.isascii() and SURROGATE.search(text) is not None


def shown_text(text: str) -> str:
    """``text`` with any lone surrogate replaced by U+FFFD: for paths and messages."""
    return text if text.isascii() else SURROGATE.sub("\ufffd", text)


def check_text(value: object) -> object:
    """A string without lone surrogates; anything else for the ``str`` schema to refuse."""
    if not isinstance(value, str) or value.isascii() or SURROGATE.search(value) is None:
        return value
    raise PydanticCustomError("string_unicode", SURROGATE_MSG)


#: A ``str`` field: no lone surrogates (pydantic's plain ``str`` lets them through). The
#: check runs before the ``str`` schema, so that a field's ``max_length`` is that
#: schema's own ("String should have at most 128 characters"), not a generic length.
Text = Annotated[str, BeforeValidator(check_text)]

#: Control characters (C0, DEL, C1): a terminal obeys them rather than showing them.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


#: Characters that reorder the text around them on a screen (bidirectional embeddings,
#: overrides and isolates, and the marks that set a direction: the Arabic letter mark,
#: the left-to-right and right-to-left marks): a name holding one can read as another.
BIDI_CONTROLS = re.compile("[\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069]")

#: The line and paragraph separators: line breaks that are no control characters.
LINE_SEPARATORS = re.compile("[\u2028\u2029]")

#: Characters a screen does not show (the zero-width space, the word joiner and the
#: invisible operators, the byte-order mark, the soft hyphen, the Mongolian vowel
#: separator, the interlinear annotations, the tags): two names that read alike differ
#: by one. The zero-width joiner and non-joiner are kept: scripts and emoji need them.
INVISIBLES = re.compile("[\u00ad\u180e\u200b\u2060-\u2064\ufeff\ufff9-\ufffb\U000e0000-\U000e007f]")

#: What a terminal is given escaped (``\u2028``) rather than as it is, besides the
#: control characters (:func:`escape_controls`).
UNSHOWN = re.compile(f"{BIDI_CONTROLS.pattern}|{LINE_SEPARATORS.pattern}|{INVISIBLES.pattern}")


def escape_unshown(text: str) -> str:
    """``text`` with each character of :data:`UNSHOWN` as its escape (``\\u202e``)."""
    return UNSHOWN.sub(_escaped, text)


def _escaped(found: re.Match[str]) -> str:
    code = ord(found.group())
    return f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}"


def screen_rule(what: str) -> Callable[[object], object]:
    """The one rule for text people read on a console or a terminal (``what``: how the
    refusal names it, "a name"): no control characters, nor characters that reorder the
    text around them. Anything but a string is left for the ``str`` schema to refuse."""

    def check(value: object) -> object:
        if not isinstance(value, str):
            return value
        if _CONTROL.search(value) is not None or LINE_SEPARATORS.search(value) is not None:
            raise PydanticCustomError(
                "string_control",
                f"{what} is shown on screens: no control characters nor line breaks",
            )
        if BIDI_CONTROLS.search(value) is not None:
            raise PydanticCustomError(
                "string_bidi",
                f"{what} is shown on screens: no characters that reorder the text "
                "(U+061C, U+200E, U+200F, U+202A to U+202E, U+2066 to U+2069)",
            )
        if (found := INVISIBLES.search(value)) is not None:
            raise PydanticCustomError(
                "string_invisible",
                f"{what} is shown on screens: no characters a screen does not show "
                f"(U+{ord(found.group()):04X} here)",
            )
        return value

    return check


check_label = screen_rule("a name")
check_note = screen_rule("this text")


def escape_controls(text: str) -> str:
    """``text`` with each control character shown as its escape (``\\x1b``), for a
    message that quotes what a client sent."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


#: A name people read on a console or a terminal (a vehicle's, a zone's, an obstacle's):
#: ``Text`` without control characters (NUL, escape sequences, line breaks) nor characters
#: that reorder the text.
Label = Annotated[str, BeforeValidator(check_text), BeforeValidator(check_label)]

#: Other text a person types for others to read (a reason given with a refusal): the
#: same rule as :data:`Label`, its refusal naming it "this text".
Note = Annotated[str, BeforeValidator(check_text), BeforeValidator(check_note)]

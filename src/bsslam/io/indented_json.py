"""``json.dumps(value, indent=k, allow_nan=False)`` of documents made mostly of number
lists, the same text at a fraction of the time.

With an indent, the standard library encodes in pure Python, a few generator calls per
number (CPython 3.11's C encoder only does compact output): a map's hundreds of thousands
of numbers took most of a second. Here a list of plain floats or ints is one ``join`` of
their ``repr`` (what the json module writes for them); everything else goes the
standard library's way, element by element.

:func:`dumps_compact` is ``json.dumps(value)`` (its default separators, NaN allowed) of
such documents holding numpy arrays: the C encoder would need them as nested lists, whose
building costs more than the encoding.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

# json.dumps' defaults: ", " and ": " separators, NaN and infinities allowed, ASCII
_COMPACT = json.JSONEncoder()
# An indent makes the encoder the pure-Python one, whose error messages (naming the bad
# float) are those of the indented text; a scalar's text does not depend on it.
_SCALAR = json.JSONEncoder(allow_nan=False, indent=0)


def dumps_indented(value: Any, indent: int) -> str:
    """The text of ``json.dumps(value, indent=indent, allow_nan=False)``.

    Raises:
        ValueError: a float is NaN or infinite (as the json module does).
        TypeError: a value JSON cannot hold.
    """
    return _encode(value, " " * indent, "\n")


def _encode(value: Any, step: str, newline: str) -> str:
    """``value`` at the nesting whose line break plus indentation is ``newline``."""
    if isinstance(value, dict):
        if not value:
            return "{}"
        inner = newline + step
        parts = []
        for key, item in value.items():
            parts.append(f"{_key(key)}: {_encode(item, step, inner)}")
        return "{" + inner + ("," + inner).join(parts) + newline + "}"
    if isinstance(value, (list, tuple)):
        if not value:
            return "[]"
        inner = newline + step
        numbers = _number_texts(value)
        parts = numbers if numbers is not None else [_encode(item, step, inner) for item in value]
        return "[" + inner + ("," + inner).join(parts) + newline + "]"
    return _scalar(value)


def _scalar(value: Any) -> str:
    """One value that is not a container, as the json module writes it."""
    kind = type(value)
    if kind is int:
        return int.__repr__(value)
    if kind is float:
        if not math.isfinite(value):
            raise ValueError(f"Out of range float values are not JSON compliant: {value!r}")
        return float.__repr__(value)
    if kind is str:
        return json.encoder.encode_basestring_ascii(value)
    if value is None:
        return "null"
    # bools, subclasses and the rest: the json module's own way (slow, but rare here)
    return _SCALAR.encode(value)


def _number_texts(items: list | tuple) -> list[str] | None:
    """The json texts of ``items`` when every one is a plain float or a plain int (not a
    bool or a subclass), else None."""
    kinds = set(map(type, items))
    if kinds == {float}:
        if not all(map(math.isfinite, items)):
            bad = next(v for v in items if not math.isfinite(v))
            raise ValueError(f"Out of range float values are not JSON compliant: {bad!r}")
        return list(map(float.__repr__, items))
    if kinds == {int}:
        return list(map(int.__repr__, items))
    return None


def _key(key: Any) -> str:
    """A dict key as the json module writes it (keys that are not strings are converted
    as it converts them)."""
    if isinstance(key, str):
        return json.encoder.encode_basestring_ascii(key)
    text = _SCALAR.encode({key: 0})      # the json module's conversion and errors
    return text[2:text.rindex(":")]


def dumps_compact(value: Any) -> str:
    """The text of ``json.dumps(value)``, numpy arrays taken as their ``tolist()``.

    Raises:
        TypeError: a value JSON cannot hold.
    """
    if isinstance(value, np.ndarray):
        return _compact_array(value)
    if isinstance(value, dict) and all(type(key) is str for key in value):
        return "{" + ", ".join(json.encoder.encode_basestring_ascii(key) + ": " + dumps_compact(item)
                               for key, item in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(map(dumps_compact, value)) + "]"
    return _COMPACT.encode(value)     # scalars, and dicts with other keys (holding no arrays)


def _compact_array(a: np.ndarray) -> str:
    """``json.dumps(a.tolist())``, the numbers of a non-empty, finite 1-D or 2-D float or
    integer array formatted in one pass (NaN and infinities go the json module's way)."""
    if (a.dtype.kind not in "fiu" or a.ndim not in (1, 2) or a.size == 0
            or (a.dtype.kind == "f" and not np.all(np.isfinite(a)))):
        return _COMPACT.encode(a.tolist())
    flat = a.ravel().tolist()
    texts = list(map(float.__repr__ if a.dtype.kind == "f" else int.__repr__, flat))
    if a.ndim == 1:
        return "[" + ", ".join(texts) + "]"
    width = a.shape[1]
    return "[[" + "], [".join(", ".join(texts[i:i + width]) for i in range(0, len(texts), width)) + "]]"

"""Typed reads of the values a scene file holds: readers call these instead of float(), int() or indexing.

A value of the wrong type or out of range becomes a SceneError naming the file, the field, the value and
what to do, so a hand-edited or truncated file never reaches the maths as a ZeroDivisionError or a NaN.
What the values mean together (a positive focal length, a rigid pose, 0 < near < far) is checked once for
every format in common.check_views.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from insertnerf_cli.errors import SceneError

FIX = "correct the file or re-export the scene"
_SHOWN_CHARS = 40  # a bad value longer than this is cut in messages


def show(value: Any) -> str:
    """A value for a message: its repr, cut to a readable length."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


def bad_value(source: Path | str, field: str, value: Any, want: str) -> SceneError:
    return SceneError(f"{source}: {field} must be {want}, got {show(value)}; {FIX}")


def number(value: Any, field: str, source: Path | str, low: float | None = None, high: float | None = None,
           unit: str = "") -> float:
    """A finite number strictly between ``low`` and ``high`` (each optional); ``unit`` is named in the message."""
    if low is not None and high is not None:
        want = f"a number between {low:g} and {high:g}{unit} (exclusive)"
    elif low is not None:
        want = f"a number greater than {low:g}{unit}"
    else:
        want = f"a finite number{unit}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise bad_value(source, field, value, want)
    x = float(value)
    if not math.isfinite(x) or (low is not None and x <= low) or (high is not None and x >= high):
        raise bad_value(source, field, value, want)
    return x


def whole(value: Any, field: str, source: Path | str) -> int:
    """A positive whole number (an integral float such as 480.0 is accepted)."""
    x = number(value, field, source, low=0.0)
    if x != int(x):
        raise bad_value(source, field, value, "a positive whole number")
    return int(x)


def text(value: Any, field: str, source: Path | str) -> str:
    """A non-empty string usable as a file path."""
    if not isinstance(value, (str, os.PathLike)) or not str(value) or "\0" in str(value):
        raise bad_value(source, field, value, "a relative file path (text)")
    return str(value)


def listing(value: Any, field: str, source: Path | str) -> list[Any]:
    """A JSON list."""
    if not isinstance(value, list):
        raise bad_value(source, field, value, "a list")
    return value


def objects(value: Any, field: str, source: Path | str) -> list[dict[str, Any]]:
    """A JSON list whose entries are all objects (e.g. the frames of a transforms file)."""
    items = listing(value, field, source)
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise bad_value(source, f"{field}[{i}]", item, "an object with the frame's keys")
    return items


def matrix(value: Any, field: str, source: Path | str, shapes: Sequence[tuple[int, ...]]) -> np.ndarray:
    """A float64 array of one of ``shapes`` whose entries are all finite."""
    want = " or ".join("x".join(str(n) for n in s) for s in shapes) + " matrix of finite numbers"
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise bad_value(source, field, value, f"a {want}") from None
    if array.shape not in [tuple(s) for s in shapes] or not np.isfinite(array).all():
        raise bad_value(source, field, value, f"a {want}")
    return array

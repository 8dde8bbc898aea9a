"""Values of the options that the command line and batch job files share.

Each parser takes an option's command-line text or its TOML value and
returns the checked value, or raises ``ValueError`` with a reason ("must be
…") that the caller prefixes with the option's name (:func:`checked` does).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from .camera import MAX_IMAGE_SIDE
from .errors import InputError

__all__ = ["MAX_PARTS", "checked", "parse_background", "parse_focal", "parse_scene_background", "parse_size",
           "parse_parts", "parse_part_seeds", "parse_point", "parse_box"]

#: Most rigid parts ``--parts`` may ask for.
MAX_PARTS = 8


def checked(option: str, parse: Callable[[Any], Any], value: Any) -> Any:
    """``value`` checked by one of the parsers here; None stays None. A bad value raises
    :class:`~marionette.errors.InputError` ``"{option} {reason}, got {value!r}"``."""
    if value is None:
        return None
    try:
        return parse(value)
    except ValueError as e:
        raise InputError(f"{option} {e}, got {value!r}") from None


def _numbers(value: Any, count: int, separator: str) -> list[float]:
    """``count`` finite numbers: a list, or a string of them joined by ``separator``."""
    if isinstance(value, str):
        try:
            value = [float(x) for x in value.lower().split(separator)]
        except ValueError:
            value = None
    if (not isinstance(value, list) or len(value) != count
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
        raise ValueError(f"must be {count} numbers joined by '{separator}'" if count > 1 else "must be a number")
    return [float(x) for x in value]


def parse_background(value: Any) -> tuple[float, float, float]:
    """``"R,G,B"`` or ``[R, G, B]``, components all within 0-1 or 0-255 → floats in [0, 1]."""
    rgb = _numbers(value, 3, ",")
    if min(rgb) < 0 or max(rgb) > 255:
        raise ValueError("must be R,G,B within 0-1 or 0-255")
    scale = 255.0 if max(rgb) > 1 else 1.0
    return rgb[0] / scale, rgb[1] / scale, rgb[2] / scale


def parse_scene_background(value: Any) -> tuple[float, float, float] | str:
    """``"scene"`` (the photo's own scene) or a colour as :func:`parse_background` reads it."""
    if value == "scene":
        return "scene"
    try:
        return parse_background(value)
    except ValueError:
        raise ValueError("must be R,G,B within 0-1 or 0-255, or 'scene'") from None


def parse_point(value: Any) -> tuple[float, float]:
    """``"X,Y"`` or ``[X, Y]``, pixel coordinates → floats."""
    try:
        x, y = _numbers(value, 2, ",")
    except ValueError:
        raise ValueError("must be X,Y (two numbers, pixels)") from None
    return x, y


def parse_box(value: Any) -> tuple[float, float, float, float]:
    """``"X0,Y0,X1,Y1"`` or a list of four, pixel coordinates → floats (checked against the image later)."""
    try:
        x0, y0, x1, y1 = _numbers(value, 4, ",")
    except ValueError:
        raise ValueError("must be X0,Y0,X1,Y1 (four numbers, pixels)") from None
    return x0, y0, x1, y1


def parse_size(value: Any) -> tuple[int, int]:
    """``"WIDTHxHEIGHT"`` or ``[WIDTH, HEIGHT]``, integers within 16..MAX_IMAGE_SIDE."""
    w, h = _numbers(value, 2, "x")
    if not (w == int(w) and h == int(h) and 16 <= w <= MAX_IMAGE_SIDE and 16 <= h <= MAX_IMAGE_SIDE):
        raise ValueError(f"must be WIDTHxHEIGHT, integers within 16..{MAX_IMAGE_SIDE}")
    return int(w), int(h)


def parse_focal(value: Any) -> float | str:
    """``"auto"`` (estimate it) or a focal length in pixels, a positive number (or its digits)."""
    if value == "auto":
        return "auto"
    try:
        focal = float(value)
    except (TypeError, ValueError):
        focal = float("nan")
    if isinstance(value, bool) or not (math.isfinite(focal) and focal > 0):
        raise ValueError("must be 'auto' or a positive number of pixels")
    return focal


def parse_parts(value: Any) -> int | str:
    """``"auto"`` or a part count 1..MAX_PARTS (an integer or its digits)."""
    if value == "auto":
        return "auto"
    if isinstance(value, str) and value.isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_PARTS:
        raise ValueError(f"must be 'auto' or an integer from 1 to {MAX_PARTS}")
    return value


def parse_part_seeds(value: Any) -> dict[int, tuple[float, float]]:
    """Target pixels seeding parts: ``["K:X,Y", …]`` (command line) or ``{K = [X, Y], …}`` (TOML) → {K: (X, Y)}."""
    if isinstance(value, list) and all(isinstance(item, str) for item in value):
        value = dict(item.partition(":")[::2] for item in value)  # "K:X,Y" → {"K": "X,Y"}
    if not (isinstance(value, dict) and value and all(isinstance(k, str) and k.isdigit() and xy
                                                      for k, xy in value.items())):
        raise ValueError("must be K:X,Y (part, target pixel), or the table {K = [X, Y], …} in a job file")
    return {int(part): tuple(_numbers(xy, 2, ",")) for part, xy in value.items()}

"""Command-line values both processes accept (``--size``, ``--background``, bounded numbers): parsers
for argparse that raise ``ArgumentTypeError`` with a message a user can act on."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import PurePath

from tessera.scheduling.refinement import ADAPTIVE, MAX_STILL_SAMPLES


def command_name(argv0: str, module: str) -> str:
    """How the user started the process, for its usage line: the console script's name
    (``tessera-server``) when run by one, else ``python -m MODULE``."""
    name = PurePath(argv0).name
    return name if name.startswith("tessera-") else f"python -m {module}"


def size_parser(minimum: int, maximum: int) -> Callable[[str], tuple[int, int]]:
    """A parser of ``WxH`` (e.g. 1280x720) → (w, h), each side in ``minimum``…``maximum`` pixels."""

    def parse_size(text: str) -> tuple[int, int]:
        try:
            width, height = (int(part) for part in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 1280x720, got {text!r}") from None
        if not (minimum <= width <= maximum and minimum <= height <= maximum):
            raise argparse.ArgumentTypeError(f"size sides must be {minimum}…{maximum} pixels, got {text!r}")
        return width, height

    return parse_size


def number_parser(minimum: float = -math.inf, above: bool = False, note: str = "",
                  maximum: float = math.inf) -> Callable[[str], float]:
    """A parser of a finite number ≥ ``minimum`` (> when ``above``) and ≤ ``maximum``; ``note`` ends
    the error message."""
    bound = "" if minimum == -math.inf else f" {'>' if above else '>='} {minimum:g}"
    bound += "" if maximum == math.inf else f"{' and' if bound else ''} <= {maximum:g}"

    def parse_number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < minimum or (above and value == minimum) or value > maximum:
            raise argparse.ArgumentTypeError(f"must be a finite number{bound}{note}, got {text!r}")
        return value

    return parse_number


def parse_background(text: str) -> tuple[float, float, float]:
    """``#rrggbb`` or ``r,g,b`` with components in 0…1 → an RGB triple in 0…1."""
    text = text.strip()
    try:
        if text.startswith("#") and len(text) == 7:
            rgb = tuple(int(text[i:i + 2], 16) / 255.0 for i in (1, 3, 5))
        else:
            rgb = tuple(float(v) for v in text.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in rgb):
        raise argparse.ArgumentTypeError(f"background must be '#rrggbb' or 'r,g,b' in 0…1, got {text!r}")
    return rgb  # type: ignore[return-value]


def integer_parser(minimum: int, maximum: int, what: str, words: dict[str, int] | None = None) -> Callable[[str], int]:
    """A parser of an integer ``minimum``…``maximum`` (or one of ``words``, e.g. auto → 0); ``what``
    names it in the error message."""
    words = words or {}

    def parse_integer(text: str) -> int:
        if text.strip().lower() in words:
            return words[text.strip().lower()]
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if not minimum <= value <= maximum:
            named = "".join(f"{word} or " for word in words)
            raise argparse.ArgumentTypeError(f"{what} must be {named}an integer {minimum}..{maximum}, got {text!r}")
        return value

    return parse_integer


#: A still's samples: ``auto`` (:data:`ADAPTIVE`: until it converges) or a count 1…:data:`MAX_STILL_SAMPLES`.
parse_still_samples = integer_parser(1, MAX_STILL_SAMPLES, "samples", {"auto": ADAPTIVE})
#: An adaptive still's most samples, 2…:data:`MAX_STILL_SAMPLES`.
parse_samples_max = integer_parser(2, MAX_STILL_SAMPLES, "most samples")
#: An adaptive still's target, dB PSNR against its converged image.
parse_target_db = number_parser(0.0, above=True, note=" dB")


def parse_point_budget(text: str) -> int:
    """A point budget (issue 36): a whole number of points ≥ 1 (``1e6`` and ``1_000_000`` are taken)."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 1 or value != int(value):
        raise argparse.ArgumentTypeError(f"must be a whole number of points >= 1, got {text!r}")
    return int(value)

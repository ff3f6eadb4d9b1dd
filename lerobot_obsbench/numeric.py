"""One rule for numbers a user gives: config fields, command-line options, environment variables, grid values.

A number is refused unless it is finite (NaN passes every `<` and `>` comparison as false, so a bare `x > 0` check
lets it through), of the right kind (a whole number where a count is asked for; never a bool) and within its
bounds; the refusal names the field and says what it takes. `check_number` is the rule; `check_numbers` applies it
to each value of a sequence; `number_argument` is the same rule as an argparse type.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

from lerobot_obsbench.errors import ConfigError


def describe(
    *,
    minimum: float | None = None,
    above: float | None = None,
    maximum: float | None = None,
    below: float | None = None,
    whole: bool = False,
) -> str:
    """What a number within these bounds is, in words: "a whole number >= 1", "a finite number > 0 and <= 1"."""
    bounds = [
        f"{sign} {bound:g}"
        for sign, bound in ((">=", minimum), (">", above), ("<=", maximum), ("<", below))
        if bound is not None
    ]
    return ("a whole number" if whole else "a finite number") + (" " + " and ".join(bounds) if bounds else "")


def _fits(
    value,
    *,
    minimum: float | None = None,
    above: float | None = None,
    maximum: float | None = None,
    below: float | None = None,
    whole: bool = False,
) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    if isinstance(value, float) and not math.isfinite(value):  # (a Python int is finite, however large)
        return False
    if whole and value != int(value):
        return False
    return (
        (minimum is None or value >= minimum)
        and (above is None or value > above)
        and (maximum is None or value <= maximum)
        and (below is None or value < below)
    )


def check_number(name: str, value, *, error: type[Exception] = ConfigError, **bounds) -> int | float:
    """`value` if it is a finite number within `bounds` (`minimum`/`maximum` inclusive, `above`/`below` exclusive,
    `whole` for counts), as an int when `whole`; otherwise `error` naming `name` and what it takes."""
    if hasattr(value, "item") and getattr(value, "ndim", None) == 0:  # NumPy and torch scalars
        value = value.item()
    if not _fits(value, **bounds):
        raise error(f"{name} must be {describe(**bounds)}; got {value!r}{_written_as_text(value)}")
    return int(value) if bounds.get("whole") else value


def _written_as_text(value) -> str:
    """Why a number arrived as text, where it reads as one: YAML takes an exponent without a decimal point (1e-3)
    for a string, and a quoted number is one."""
    if not isinstance(value, str):
        return ""
    try:
        float(value)
    except ValueError:
        return ""
    mantissa, _, exponent = value.strip().lower().partition("e")
    if exponent and "." not in mantissa:
        suggestion = f"{float(mantissa):.1f}e{int(exponent)}"
        return f" (text: YAML reads an exponent without a decimal point as a string; write {suggestion})"
    return " (text: write the number without quotes)"


def check_numbers(
    name: str, values, *, length: int | None = None, error: type[Exception] = ConfigError, **bounds
) -> tuple:
    """Each of `values` checked as `check_number` does (`name[i]` in the refusal); `length` fixes how many."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise error(f"{name} must be a list of numbers; got {values!r}")
    if length is not None and len(values) != length:
        raise error(f"{name} must hold {length} numbers; got {len(values)}: {list(values)!r}")
    return tuple(check_number(f"{name}[{i}]", v, error=error, **bounds) for i, v in enumerate(values))


def parse_number(text: str, *, whole: bool = False) -> int | float:
    """A number written as text (a command-line value, an environment variable); ValueError when it is none."""
    text = text.strip()
    if whole:
        return int(text)
    return float(text)


def number_argument(**bounds):
    """argparse type applying `check_number`'s rule: argparse names the option, this says what it takes."""
    wanted = describe(**bounds)

    def parse(text: str) -> int | float:
        try:
            value = parse_number(text, whole=bounds.get("whole", False))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        if not _fits(value, **bounds):
            raise argparse.ArgumentTypeError(f"must be {wanted}, got {text}")
        return value

    return parse


def number_from_environment(variable: str, default: int | float, **bounds) -> int | float:
    """The number environment variable `variable` holds (`default` when unset), checked as `check_number` does."""
    import os

    raw = os.environ.get(variable)
    if raw is None:
        return default
    try:
        value = parse_number(raw, whole=bounds.get("whole", False))
    except ValueError:
        value = None
    if not _fits(value, **bounds):
        raise ConfigError(f"{variable}={raw!r}: must be {describe(**bounds)}")
    return value

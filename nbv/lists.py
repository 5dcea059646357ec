"""Comma lists on the command line and in configs: the one parser of indices, numbers and names.

``"0,3,5"``, ``"3, 4,50"``, ``"-x,+z"`` or an already split sequence -> a tuple, checked as asked (finite, at least
a minimum, below a count, positive, one of the allowed names, distinct, a fixed size); every error is a ValueError
that names the option and says what to write instead. Used by the ``fluidgs`` options (:mod:`apps.options`:
``--candidates``, ``--views``, ``--initial-views``, ``--initial-direction``, ``--velocities``, ``--directions``)
and by the library's own readers (:func:`nbv.physics.parse_directions`, :func:`nbv.study.sweep.parse_velocities`).
Standard library only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["parse_list"]

_EXAMPLES = {int: "0,3,5", float: "3,5,10"}


def parse_list(
    text: str | Sequence[Any] | None,
    item: Callable[[str], Any] = str,
    option: str = "the list",
    *,
    minimum: float | None = None,
    below: int | None = None,
    positive: bool = False,
    allowed: Sequence[str] | None = None,
    unique: bool = False,
    size: int | None = None,
    what: str | None = None,
    empty_hint: str = "",
    range_hint: str = "",
) -> tuple:
    """Parse a comma list (empty entries are skipped, so ``"0,3,"`` is ``(0, 3)``).

    Args:
        text: ``"a,b,c"`` or a sequence of entries (each converted like a string entry).
        item: the entry type: ``int``, ``float`` (must be finite) or ``str`` (whitespace stripped).
        option: the option or config key the message names (``"--candidates"``).
        minimum: entries must be >= this (for ``minimum=0`` with ints the message says indices start at 0).
        below: entries must be < this (a count of views or cameras).
        positive: entries must be > 0.
        allowed: the names an entry may be (``nbv`` probe names, for instance).
        unique: no entry may repeat.
        size: exactly this many entries.
        what: the noun of one entry for the messages ("camera", "probe", "speed in m/s").
        empty_hint, range_hint: appended to the empty-list and out-of-range messages.
    Returns:
        the entries, in the given order.
    Raises:
        ValueError: naming ``option``, the bad entries and the fix.
    """
    noun = what or "entry"
    example = _EXAMPLES.get(item, ",".join(allowed or ()) or "a,b")
    raw = [str(s).strip() for s in (text.split(",") if isinstance(text, str) else (text or ()))]
    raw = [s for s in raw if s]
    try:
        values = tuple(item(s) for s in raw)
    except (TypeError, ValueError):
        kind = {int: "integers", float: "numbers"}.get(item, f"{noun}s")
        raise ValueError(f"{option} must be a comma list of {kind} such as {example}, got {text!r}") from None
    if item is float and not all(math.isfinite(v) for v in values):
        raise ValueError(f"{option} must be finite numbers, got {text!r}")
    if not values:
        raise ValueError(
            f"{option} {text!r} lists no {noun}; give {example}" + (f", {empty_hint}" if empty_hint else "")
        )
    if size is not None and len(values) != size:
        raise ValueError(
            f"{option} must be {size} comma-separated {'numbers' if item is float else noun + 's'}, got {text!r}"
        )
    if allowed is not None:
        bad = [v for v in values if v not in allowed]
        if bad:
            raise ValueError(f"{option}: unknown {noun}s {bad}; use a comma list of {','.join(allowed)}")
    if minimum is not None:
        bad = [v for v in values if v < minimum]
        if bad:
            rule = "indices start at 0" if minimum == 0 and item is int else f"must be >= {minimum}"
            raise ValueError(f"{option} {bad}: {rule}")
    if positive and any(v <= 0 for v in values):
        raise ValueError(f"{option} must be {noun}s > 0, got {list(values)}")
    if below is not None:
        bad = [v for v in values if v >= below]
        if bad:
            raise ValueError(f"{option} {bad} out of range: " + (range_hint or f"there are {below} (0..{below - 1})"))
    if unique:
        repeated = sorted({v for v in values if values.count(v) > 1})
        if repeated:
            label = f"{noun}(s) " if what else ""
            raise ValueError(f"{option} {text!r} lists {label}{repeated} more than once; list each {noun} once")
    return values

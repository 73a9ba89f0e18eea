"""Unit strings of angle signals and channels, stated once for DBC signals and measurement files.

An angle unit converts to degrees (:data:`ANGLE_UNITS`); a count unit (:data:`COUNT_UNITS`) is an
encoder count, ``360 / counts_per_rev`` degrees. Unit strings are compared stripped and in lower case.
"""

from __future__ import annotations

import math

#: Angle units (compared in lower case) -> degrees per unit.
ANGLE_UNITS = {
    "deg": 1.0,
    "°": 1.0,
    "degree": 1.0,
    "degrees": 1.0,
    "rad": 180.0 / math.pi,
    "rev": 360.0,
    "turn": 360.0,
    "turns": 360.0,
    "arcmin": 1.0 / 60.0,
}
#: Unit strings of an encoder count (needs counts per revolution).
COUNT_UNITS = frozenset({"counts", "count", "cnt", "inc", "", "-"})


def unit_key(unit: str | None) -> str:
    """The form a unit string is looked up in (stripped, lower case; None is ``""``)."""
    return (unit or "").strip().lower()

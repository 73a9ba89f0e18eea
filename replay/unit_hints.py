"""What a log's own numbers and names say about the unit of its angles, against the unit they are read in.

Two signs that the angles are read in the wrong unit, each told as a warning naming the likely
cause, never as an error (the numbers may be right):

- :func:`radian_counts`: angles read as degrees that step by whole multiples of ``2 pi / N``
  (an encoder of ``N`` counts per revolution written out in radians) and not of ``360 / N``;
  radians read as degrees make a 0.5 deg play look like 0.0087 deg.
- :func:`named_unit`: a column whose name states its unit (``motor [rad]``, ``load (deg)``,
  ``motor_counts``) read in another one.
"""

from __future__ import annotations

import math
import re

import numpy as np

from online_backlash.codecs.units import ANGLE_UNITS, COUNT_UNITS, unit_key

#: Fewest non-zero steps from which a grid of encoder counts is told.
MIN_STEPS = 20
#: How far from a whole number a step (in grid steps) or a count per revolution may be and still count as whole.
WHOLE = 0.01
#: Fewest counts per revolution taken as an encoder's (coarser grids are too easily whole by chance).
MIN_COUNTS = 8
#: Most grid steps one sample step may span (a 32-bit encoder's revolution); a wider range of steps is no grid.
MAX_MULTIPLE = 2.0**32
#: What ends a column name that states its unit: ``motor [rad]``, ``load (deg)``, ``motor_counts``, ``load_rad``.
_NAMED_UNIT = re.compile(r"(?:[\[(]\s*([^\[\]()]+?)\s*[\])]|_([A-Za-z°]+))\s*$")


def radian_counts(angles: np.ndarray) -> int | None:
    """``N`` when ``angles`` (as read, in degrees) step by whole multiples of ``2 pi / N`` radians, an encoder
    of ``N`` counts per revolution written in radians, and not of ``360 / N`` degrees; else None.

    The grid step is the smallest non-zero step, refined over every step as the sum of the steps
    over the sum of their multiples; data that are not on a grid (filtered, interpolated, rounded
    when written) give None.

    >>> counts = np.cumsum(np.tile([1, 1, 2, -1, -3, 1], 10))
    >>> radian_counts(counts * 2 * np.pi / 16384), radian_counts(counts * 360 / 16384)
    (16384, None)
    """
    values = np.asarray(angles, dtype=float)
    steps = np.abs(np.diff(values[np.isfinite(values)]))
    steps = steps[steps > 0]
    if steps.size < MIN_STEPS or steps.min() * MAX_MULTIPLE < steps.max():  # (a damaged value: 1e-311 steps)
        return None
    multiples = steps / steps.min()
    whole = np.round(multiples)
    if np.max(np.abs(multiples - whole)) > WHOLE:
        return None
    grid = float(np.sum(steps) / np.sum(whole))
    per_radian, per_degree = 2 * math.pi / grid, 360.0 / grid
    on_radians = abs(per_radian - round(per_radian)) <= WHOLE and per_radian >= MIN_COUNTS
    if not on_radians or abs(per_degree - round(per_degree)) <= WHOLE:
        return None
    return round(per_radian)


def named_unit(column: str) -> str | None:
    """The angle or count unit a column's name states at its end (``motor [rad]``, ``load (deg)``,
    ``motor_counts``), as :func:`~online_backlash.codecs.units.unit_key` spells it; None if it states none.

    >>> named_unit("motor [°]"), named_unit("spindle_counts"), named_unit("load"), named_unit("time_s")
    ('°', 'counts', None, None)
    """
    found = _NAMED_UNIT.search(column)
    if found is None:
        return None
    unit = unit_key(found.group(1) or found.group(2))
    return unit if unit in ANGLE_UNITS or (unit and unit in COUNT_UNITS) else None


def unit_mismatch(column: str, read_as: str | None) -> str | None:
    """The unit ``column``'s name states when the angles are read in another one (``read_as``: an angle or
    count unit, None for degrees); else None."""
    named = named_unit(column)
    if named is None:
        return None
    given = unit_key(read_as or "deg")
    if named in COUNT_UNITS or given in COUNT_UNITS:
        return named if (named in COUNT_UNITS) != (given in COUNT_UNITS) else None
    return named if ANGLE_UNITS[named] != ANGLE_UNITS.get(given) else None

"""The per-block checks of every column/channel reader, as one compiled pass (numba, ``nogil``).

A block of a CSV, MDF, TDMS or Parquet log is four columns: time (s), motor, load and
optionally torque (N m), in the file's units. A row is *bad* when one of its values is not
finite, when an angle lies beyond its limit (:data:`~online_backlash.replay.tabular.MAX_ANGLE_DEG`
in the column's units: wrong units), or when its time is earlier than the last good row's time
(it goes backwards). :func:`screen_block` reads the block once, without the GIL, and returns
what :class:`~online_backlash.replay.tabular.TabularSource` needs to raise, count or drop
exactly as row-by-row checks would: the number of bad rows, the first row bad by its values, the
first row whose time goes backwards (and the time it went back from), the number of good rows
that repeat the previous good row's time, and the last good time; given an output array, it
writes the good rows there, scaled to degrees, in the same pass (a copy is needed anyway when
rows are dropped, a column is strided -- MDF records, CSV rows -- or not in degrees).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit


class Screened(NamedTuple):
    """What :func:`screen_block` found in a block (row indices count from the block's first row)."""

    bad: int  #: rows bad by value or by time
    first_value: int  #: the first row with a non-finite value or an angle beyond its limit (-1: none)
    first_backwards: int  #: the first good-valued row whose time goes backwards (-1: none)
    backwards_from: float  #: the time (s) that row went back from
    repeated: int  #: good rows whose time equals the previous good row's (or ``last_time``)
    last_time: float  #: the time of the last good row (``last_time`` if none)
    last_good: int  #: the last good row (-1: none)


def screen_block(
    columns: list[np.ndarray],
    limits: tuple[float, float],
    last_time: float,
    scales: tuple[float, float] = (1.0, 1.0),
    out: np.ndarray | None = None,
) -> Screened:
    """Check one block: ``columns`` time (s), motor, load[, torque (N m)], 1-D float64 arrays of one length.

    ``limits`` are the largest accepted motor and load magnitudes in the columns' own units;
    ``last_time`` is the last good time before the block (s; ``-inf`` at the start). If ``out``
    (float64, shape ``(4, rows)``) is given, the good rows are written to its first columns, in
    order: time, motor and load times their ``scales`` (degrees per unit), torque (NaN without
    a torque column) -- the block's samples, in the same pass.
    """
    time_s, motor, load = columns[:3]
    torque = columns[3] if len(columns) > 3 else _NONE
    found = _screen(
        time_s,
        motor,
        load,
        torque,
        float(limits[0]),
        float(limits[1]),
        float(last_time),
        float(scales[0]),
        float(scales[1]),
        _NO_OUT if out is None else out,
    )
    return Screened(*found)


_NONE = np.empty(0)
_NO_OUT = np.empty((0, 0))


@njit(cache=True, nogil=True)
def _screen(
    time_s, motor, load, torque, motor_limit, load_limit, last_time, motor_scale, load_scale, out
):  # pragma: no cover - compiled
    has_torque = torque.shape[0] > 0
    write = out.shape[0] > 0
    previous = last_time
    bad = 0
    first_value = -1
    first_backwards = -1
    backwards_from = np.nan
    repeated = 0
    good = 0
    last_good = -1
    for i in range(time_s.shape[0]):
        t = time_s[i]
        m = motor[i]
        lo = load[i]
        q = torque[i] if has_torque else np.nan
        ok = np.isfinite(t) and np.isfinite(m) and np.isfinite(lo) and abs(m) <= motor_limit and abs(lo) <= load_limit
        if has_torque and not np.isfinite(q):
            ok = False
        if not ok:
            bad += 1
            if first_value < 0:
                first_value = i
            continue
        if t < previous:
            bad += 1
            if first_backwards < 0:
                first_backwards = i
                backwards_from = previous
            continue
        if t == previous:
            repeated += 1
        previous = t
        last_good = i
        if write:
            out[0, good] = t
            out[1, good] = m * motor_scale
            out[2, good] = lo * load_scale
            out[3, good] = q
        good += 1
    return bad, first_value, first_backwards, backwards_from, repeated, previous, last_good

"""The machine's own usage clock along a log: its hour meter, read with the angles or given at the log's start.

Wear follows the use of the machine, which its controller counts (an hour meter, a cycle counter),
not the seconds a logger happened to record. A log tells the machine's hours in one of two ways:

* ``track LOG --operating-hours H``: the meter read ``H`` hours at the log's first sample; it runs
  on with the log's own time while the log records (:meth:`HourMeter.from_reading`);
* ``track LOG --hours-column NAME``: the meter recorded with the angles, a column of a CSV, MDF4,
  TDMS or Parquet log or a signal of the log's DBC (:func:`read_hour_meter`), in hours, or in
  another unit with ``--hours-unit`` (``min``, ``s``, or hours per count for a cycle counter:
  its cycle time in hours). It is read by the log's own reader in a pass of its own, as the
  angle it is not (in the unit given, no conversion), one reading per second of log time kept.

:meth:`HourMeter.hours_at` gives the meter at a log time, interpolated between readings and run
on with the log's time before the first and after the last. A meter that goes back within a log
is refused (LogFormatError naming the file).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InvalidParameterError, LogFormatError
from .replay import open_log

#: Hours per unit of an hour-meter column, by name (``--hours-unit``); a number gives hours per count.
HOURS_UNITS = {"h": 1.0, "min": 1.0 / 60.0, "s": 1.0 / 3600.0}
#: How far an hour meter may step back and still count as not going back (its rounding), hours.
METER_TOLERANCE_H = 1e-6


def hours_per_unit(text: str) -> float:
    """Hours per unit of ``--hours-unit``: ``h``, ``min``, ``s``, or a positive number (hours per count).

    >>> hours_per_unit("min") * 60, hours_per_unit("0.002")
    (1.0, 0.002)
    """
    if text in HOURS_UNITS:
        return HOURS_UNITS[text]
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise InvalidParameterError(
            f"--hours-unit must be h, min, s or hours per count (a positive number), got {text!r}"
        )
    return value


@dataclass(frozen=True)
class MachineUsage:
    """How a log tells the machine's hours (module docstring); all None: it does not.

    Attributes
    ----------
    operating_hours : float, optional
        The hour meter at the log's first sample, hours (``--operating-hours``, a manifest's per-log key).
    hours_column : str, optional
        The column or DBC signal that records the meter (``--hours-column``).
    hours_per_count : float
        Hours per unit of that column (``--hours-unit``; 1: hours).
    """

    operating_hours: float | None = None
    hours_column: str | None = None
    hours_per_count: float = 1.0

    def __post_init__(self) -> None:
        if self.operating_hours is not None and self.hours_column is not None:
            raise InvalidParameterError(
                "give the hour meter as --operating-hours (its reading at the first sample) or --hours-column, not both"
            )
        if not (math.isfinite(self.hours_per_count) and self.hours_per_count > 0):
            raise InvalidParameterError(
                f"hours per count of the hour meter must be positive, got {self.hours_per_count!r}"
            )

    @property
    def given(self) -> bool:
        """The log tells the machine's hours."""
        return self.operating_hours is not None or self.hours_column is not None

    def meter(self, path: str, first_time_s: float, log_options: dict[str, Any], time_scale: float = 1.0) -> HourMeter:
        """The meter along the log at ``path`` whose first sample is at ``first_time_s`` (seconds)."""
        if self.hours_column is not None:
            return read_hour_meter(path, self.hours_column, log_options, self.hours_per_count, time_scale)
        if self.operating_hours is None:
            raise InvalidParameterError("no hour meter given")
        return HourMeter.from_reading(self.operating_hours, first_time_s)


@dataclass(frozen=True)
class HourMeter:
    """The machine's hour meter along one log: readings (hours) at log times (seconds)."""

    time_s: np.ndarray
    hours: np.ndarray

    @classmethod
    def from_reading(cls, hours_at_first: float, first_time_s: float) -> HourMeter:
        """A meter read once, at the log's first sample (``--operating-hours``)."""
        if not (math.isfinite(hours_at_first) and hours_at_first >= 0):
            raise InvalidParameterError(
                f"--operating-hours must be a finite number of hours >= 0, got {hours_at_first!r}"
            )
        return cls(np.array([float(first_time_s)]), np.array([float(hours_at_first)]))

    def hours_at(self, time_s: float) -> float:
        """The meter at log time ``time_s`` (seconds), hours: between readings linear, outside them
        running on with the log's time."""
        first, last = float(self.time_s[0]), float(self.time_s[-1])
        inside = float(np.interp(time_s, self.time_s, self.hours))
        return inside + (max(time_s - last, 0.0) - max(first - time_s, 0.0)) / 3600.0


def meter_log_options(log_options: dict[str, Any], column: str) -> dict[str, Any]:
    """Reader options that read the hour-meter ``column`` of a log as its angles (no unit conversion)."""
    options = dict(log_options)
    if "motor_signal" in options:  # a CAN log with a DBC
        options.update(motor_signal=column, load_signal=column, units="deg", wrap_deg=None)
        return options
    if "serial_format" not in options and options.get("eds") is None:  # CSV, MDF, TDMS, Parquet
        time = {k: v for k, v in (options.get("columns") or {}).items() if k == "time"}
        options.update(columns={**time, "motor": column, "load": column}, units="deg", motor_cpr=None, load_cpr=None)
        return options
    raise InvalidParameterError(
        "--hours-column names a column of a CSV, MDF4, TDMS or Parquet log or a signal of a DBC-decoded CAN log; "
        "for this log give the meter's reading at its first sample with --operating-hours H"
    )


def read_hour_meter(
    path: str | os.PathLike[str],
    column: str,
    log_options: dict[str, Any],
    hours_per_count: float = 1.0,
    time_scale: float = 1.0,
) -> HourMeter:
    """The hour meter recorded in ``column`` of a log (module docstring).

    ``hours_per_count`` converts the column to hours; ``time_scale`` its time to seconds (as the
    angles' pass reads it). LogFormatError names the file when the column is missing, holds no
    reading, or goes back.
    """
    path = os.fspath(path)
    times, values = [], []
    try:
        with open_log(path, **meter_log_options(log_options, column)) as reader:
            for chunk in reader.iter_chunks():
                t = np.asarray(chunk.time_s, dtype=float) * time_scale
                keep = np.ones(t.size, dtype=bool)
                keep[1:] = np.floor(t[1:]) != np.floor(t[:-1])  # one reading per second of log time
                keep[-1] = True
                times.append(t[keep])
                values.append(np.asarray(chunk.motor_deg, dtype=float)[keep] * hours_per_count)
    except LogFormatError as exc:
        raise LogFormatError(path, exc.line, f"hour meter column {column!r}: {exc.reason}") from exc
    if not times:
        raise LogFormatError(path, None, f"hour meter column {column!r}: no readings")
    time_s, hours = np.concatenate(times), np.concatenate(values)
    back = np.flatnonzero(np.diff(hours) < -METER_TOLERANCE_H)
    if back.size:
        i = int(back[0])
        raise LogFormatError(
            path,
            None,
            f"hour meter column {column!r} goes back from {hours[i]:g} to {hours[i + 1]:g} h at {time_s[i + 1]:g} s",
        )
    return HourMeter(time_s, hours)

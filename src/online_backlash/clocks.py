"""Where a log lies in calendar time, and in which unit its time column counts.

A log's samples carry ``time_s`` on the recorder's clock. :func:`log_clock` places them in calendar
time (UNIX seconds, UTC) by the first of these that a log has, in this order:

1. ``--start`` (one log) or a log's ``start`` in a fleet manifest: the user's word
   (:data:`CLOCK_START`);
2. ``--start-from-name PATTERN``: the start written in the file's name, a :func:`time.strftime`
   pattern such as ``%Y-%m-%d_%H%M%S`` found anywhere in the name (:func:`start_from_name`,
   :data:`CLOCK_NAME`);
3. the time column itself, when it holds UNIX times (:data:`CLOCK_UNIX`);
4. the recording's own clock: an MDF4 header's start time, a TDMS ``wf_start_time``, the first
   timestamp of a Parquet timestamp column
   (:attr:`~online_backlash.stream.SampleSource.time_origin_unix_s`);
5. the file's modification time, taken as the time of its first sample (:data:`CLOCK_MTIME`): the
   last resort, since a copy made without preserving times (``cp``, a download, an e-mail) moves it.

The time column is in seconds. A log whose time steps by more than :data:`MAX_PERIOD_S` from one
sample to the next (on average over its first samples: a clock that stamps whole seconds on many
samples a second is seconds) is not an encoder log in seconds: its time is
read in the first of milliseconds and microseconds that gives a plausible sample period, with a
:class:`~online_backlash.errors.BacklashWarning` that says so (:func:`time_unit_scale`;
``--time-unit`` overrides), so that milliseconds under a seconds header do not count 1000 times
the operating hours.
"""

from __future__ import annotations

import datetime as dt
import os
import re
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .errors import BacklashWarning, InvalidParameterError, LogFormatError
from .stream import UNIX_TIME_MIN

#: The clocks a log's samples can be placed by (``TrackResult.clock``); a recording's own clock is
#: named by its reader (``time_origin_name``, e.g. "MDF header start time").
CLOCK_START, CLOCK_NAME, CLOCK_UNIX = "--start", "file name", "UNIX time column"
CLOCK_MTIME, CLOCK_LIVE = "file modification time", "live: first sample is now"

#: Units of a log's time column, seconds per unit (``--time-unit``).
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
#: The longest plausible sample period of an encoder log, seconds: a time column that steps by
#: more is read in a smaller unit (:func:`time_unit_scale`).
MAX_PERIOD_S = 0.2
#: Samples whose time steps decide the unit of a time column.
PERIOD_SAMPLES = 1000


class LogClock(NamedTuple):
    """How a log's ``time_s`` becomes calendar time: ``offset_s`` seconds to add, and the clock's name."""

    offset_s: float
    name: str


@dataclass(frozen=True)
class ClockOptions:
    """What the user says about a log's clock.

    Attributes
    ----------
    start_unix_s : float, optional
        Calendar time of the log's first sample, UNIX seconds (``--start``, a manifest's per-log ``start``).
    start_pattern : str, optional
        A :func:`time.strftime` pattern of the start written in the file's name (``--start-from-name``).
    time_unit : str, optional
        Unit of the time column (a key of :data:`TIME_UNITS`); None: seconds, or found from the sample period.
    """

    start_unix_s: float | None = None
    start_pattern: str | None = None
    time_unit: str | None = None

    def __post_init__(self) -> None:
        if self.time_unit is not None and self.time_unit not in TIME_UNITS:
            raise InvalidParameterError(f"time unit must be one of {', '.join(TIME_UNITS)}, got {self.time_unit!r}")
        if self.start_pattern is not None:
            pattern_regex(self.start_pattern)  # refused early, before any log is read


def log_clock(
    path: str | os.PathLike[str],
    first_time_s: float,
    start_unix_s: float | None = None,
    origin: tuple[float | None, str] = (None, ""),
    start_pattern: str | None = None,
) -> LogClock:
    """The clock of a log whose first sample is at ``first_time_s`` (see the module docstring).

    ``origin`` is the recording's own clock: UNIX time of its ``time_s = 0`` and what it was read
    from (a reader's ``time_origin_unix_s`` and ``time_origin_name``).
    """
    if start_unix_s is not None:
        return LogClock(start_unix_s - first_time_s, CLOCK_START)
    if start_pattern is not None:
        return LogClock(start_from_name(path, start_pattern) - first_time_s, f"{CLOCK_NAME} ({start_pattern})")
    if first_time_s >= UNIX_TIME_MIN:
        return LogClock(0.0, CLOCK_UNIX)
    if origin[0] is not None:
        return LogClock(origin[0], origin[1])
    return LogClock(os.stat(path).st_mtime - first_time_s, CLOCK_MTIME)


#: strftime directives and what they match in a file name.
_DIRECTIVES = {
    "Y": r"\d{4}",
    "y": r"\d{2}",
    "m": r"\d{1,2}",
    "d": r"\d{1,2}",
    "H": r"\d{1,2}",
    "M": r"\d{1,2}",
    "S": r"\d{1,2}",
    "f": r"\d{1,6}",
    "j": r"\d{1,3}",
    "b": r"[A-Za-z]{3}",
    "B": r"[A-Za-z]+",
    "z": r"[+-]\d{2}:?\d{2}|Z",
    "%": "%",
}


def pattern_regex(pattern: str) -> re.Pattern[str]:
    """The regular expression that finds a :func:`time.strftime` ``pattern`` in a file name.

    >>> pattern_regex("%Y-%m-%d_%H%M%S").search("rig7_2026-11-02_080000.csv").group(0)
    '2026-11-02_080000'
    """
    parts, i = [], 0
    while i < len(pattern):
        if pattern[i] == "%" and i + 1 < len(pattern):
            code = pattern[i + 1]
            if code not in _DIRECTIVES:
                raise InvalidParameterError(
                    f"--start-from-name {pattern!r}: %{code} is not a date or time field; "
                    "use %Y %y %m %d %H %M %S %f %j %b %B %z"
                )
            parts.append(f"(?:{_DIRECTIVES[code]})")
            i += 2
        else:
            parts.append(re.escape(pattern[i]))
            i += 1
    if not any(c in pattern for c in ("%Y", "%y")):
        raise InvalidParameterError(
            f"--start-from-name {pattern!r} has no year (%Y or %y): it cannot place a log in time"
        )
    return re.compile("".join(parts))


def start_from_name(path: str | os.PathLike[str], pattern: str) -> float:
    """The start written in a log's file name by ``pattern`` (UTC unless it has ``%z``), UNIX seconds.

    LogFormatError naming the file when its name holds no such date.

    >>> start_from_name("logs/gb7_2026-11-02_080000.csv", "%Y-%m-%d_%H%M%S")
    1793606400.0
    """
    name = os.path.basename(os.fspath(path))
    for match in pattern_regex(pattern).finditer(name):
        try:
            when = dt.datetime.strptime(match.group(0), pattern)
        except ValueError:
            continue
        if when.tzinfo is None:
            when = when.replace(tzinfo=dt.timezone.utc)
        return when.timestamp()
    raise LogFormatError(
        os.fspath(path), None, f"its name holds no start time in the form {pattern!r} (--start-from-name)"
    )


#: Patterns tried on the names of logs that overlap by their modification times, to suggest one.
NAME_PATTERNS = (
    "%Y-%m-%d_%H%M%S",
    "%Y-%m-%d_%H-%M-%S",
    "%Y-%m-%dT%H%M%S",
    "%Y-%m-%dT%H-%M-%S",
    "%Y%m%d_%H%M%S",
    "%Y%m%dT%H%M%S",
    "%Y%m%d-%H%M%S",
    "%Y-%m-%d %H-%M-%S",
    "%Y-%m-%d_%H%M",
    "%Y%m%d%H%M%S",
    "%Y-%m-%d",
    "%Y%m%d",
)


def suggest_name_pattern(*paths: str | os.PathLike[str]) -> str | None:
    """The first of :data:`NAME_PATTERNS` that reads a start from every one of ``paths``' names,
    giving them different starts (None if none does)."""
    for pattern in NAME_PATTERNS:
        try:
            starts = [start_from_name(p, pattern) for p in paths]
        except LogFormatError:
            continue
        if len(set(starts)) == len(starts):
            return pattern
    return None


def time_unit_scale(time_s: np.ndarray, unit: str | None = None, source: str = "") -> float:
    """Seconds per unit of a log's time column: ``unit`` (:data:`TIME_UNITS`) if given, else found
    from the mean step of its first :data:`PERIOD_SAMPLES` samples (module docstring), with a
    BacklashWarning naming ``source`` when that is not seconds.

    >>> time_unit_scale(np.arange(0.0, 5.0, 0.001))
    1.0
    >>> import warnings
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")  # it says: read as ms (1000 Hz)
    ...     time_unit_scale(np.arange(0.0, 5000.0, 1.0))
    0.001
    """
    if unit is not None:
        return TIME_UNITS[unit]
    first = np.asarray(time_s[: PERIOD_SAMPLES + 1], dtype=float)
    if first.size < 2 or not first[-1] > first[0]:
        return 1.0
    period = float(first[-1] - first[0]) / (first.size - 1)
    if period <= MAX_PERIOD_S:
        return 1.0
    for name, scale in TIME_UNITS.items():
        if scale < 1.0 and period * scale <= MAX_PERIOD_S:
            warnings.warn(
                f"{source}: its time column steps by {period:g} from sample to sample: in seconds that would be an "
                f"encoder log at {1.0 / period:.3g} Hz; read as {name} ({1.0 / (period * scale):.4g} Hz, so that its "
                "operating hours are not multiplied); give --time-unit s to keep seconds",
                BacklashWarning,
                stacklevel=2,
            )
            return scale
    return 1.0

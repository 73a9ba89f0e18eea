"""What every column- or channel-based log shares: roles, units, validation, alignment.

CSV logs (:mod:`~online_backlash.replay.csv`), ASAM MDF (:mod:`~online_backlash.replay.mdf`),
NI TDMS (:mod:`~online_backlash.replay.tdms`) and Parquet/Arrow
(:mod:`~online_backlash.replay.parquet`) map their columns or channels to the roles ``time``,
``motor``, ``load`` and ``torque`` (``columns=``), convert the angles to degrees by a unit
(:func:`unit_scale`), and validate blocks the same way (:class:`TabularSource`): a non-finite
value or a time that goes backwards raises :class:`~online_backlash.errors.LogFormatError`
naming the file, the row and the column, or with ``skip_bad=True`` is counted in
``counters.corrupt``; a time step longer than three nominal periods is a gap. An angle beyond
:data:`MAX_ANGLE_DEG` is refused like a non-finite one (wrong units: no float64 fit resolves it).
At the end of a pass, a time column that never advances is an error, and samples that repeat the
previous sample's time are counted in one :class:`~online_backlash.errors.BacklashWarning`.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import warnings
from abc import abstractmethod
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from online_backlash.codecs.gaps import GapDetector
from online_backlash.codecs.units import ANGLE_UNITS, COUNT_UNITS
from online_backlash.errors import BacklashWarning, InvalidParameterError, LogFormatError
from online_backlash.stream import SampleChunk, SampleSource, StreamCounters, rechunk

from .block_checks import Screened, screen_block
from .signatures import check_signature, library_failure
from .unit_hints import radian_counts, unit_mismatch

ROLES = ("time", "motor", "load", "torque")
REQUIRED = ("time", "motor", "load")
#: Column or channel names that look like a torque (a note says so where one is present but not read).
TORQUE_LIKE = re.compile(r"torque|drehmoment|moment|(^|[^a-z])tq([^a-z]|$)|[_ \[(]n ?[.*·]? ?m\b", re.IGNORECASE)

#: Largest angle magnitude accepted, degrees: float64 spaces numbers beyond it more than 0.1 deg apart,
#: so no play can be resolved (and squares of such values overflow in a fit).
MAX_ANGLE_DEG = 1e15

#: Time units -> seconds per unit.
TIME_UNITS = {"s": 1.0, "sec": 1.0, "": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
#: Torque units -> N m per unit.
TORQUE_UNITS = {"nm": 1.0, "n m": 1.0, "n·m": 1.0, "n*m": 1.0, "n.m": 1.0, "": 1.0, "mnm": 1e-3, "knm": 1e3}


def angle_scale(units: str | None, cpr: float | None, which: str) -> float:
    """Degrees per unit of a motor or load column (``which`` names it in errors).

    ``units`` is an angle unit (``deg``, ``rad``, ``rev``, ...: :data:`ANGLE_UNITS`, any case),
    ``counts`` (then ``cpr``, counts per revolution, is needed) or None (degrees).
    """
    if units is None:
        return 1.0
    try:
        return unit_scale(units, cpr, which)
    except LogFormatError as exc:  # a setting, not a file's content
        raise InvalidParameterError(exc.reason) from None


def unit_scale(unit: str, cpr: float | None, which: str, channel: str | None = None, path: str | None = None) -> float:
    """Degrees per unit of an angle channel whose unit string is ``unit``.

    Angle units convert to degrees; a count unit (:data:`COUNT_UNITS`) is an encoder count,
    ``360 / cpr`` degrees. Any other unit raises LogFormatError naming the ``which`` channel
    ``channel`` of file ``path`` and its unit.
    """
    key = unit.strip().lower()
    if key in ANGLE_UNITS:
        return ANGLE_UNITS[key]
    name = which if channel is None else f"{which} channel {channel!r}"
    if key in COUNT_UNITS:
        if cpr is None or not math.isfinite(cpr) or cpr <= 0:
            raise LogFormatError(
                path or "",
                None,
                f"{name} is in encoder counts (unit {unit!r}): needs a positive {which}_cpr (--{which}-cpr), got "
                f"{cpr!r}",
            )
        return 360.0 / cpr
    raise LogFormatError(
        path or "",
        None,
        f"{name} has unit {unit!r}, not an angle ({', '.join(sorted(ANGLE_UNITS))}) or a count; override with "
        "units=/--units",
    )


def channel_scales(
    path: str,
    names: dict[str, str],
    units: dict[str, str | None],
    override: str | None,
    motor_cpr: float | None,
    load_cpr: float | None,
) -> tuple[float, float, float, float]:
    """Scales (seconds, motor degrees, load degrees, N m per unit) from the channels' own units.

    ``units`` maps each role to its channel's unit string (None where the format has none:
    seconds, degrees, N m). ``override`` (``units=``) replaces the motor and load units. A motor
    or load unit that is neither an angle nor a count raises LogFormatError naming both channels
    and their units (a unit mismatch), as do unknown time or torque units.
    """
    time_scale = _lookup(TIME_UNITS, units.get("time"), "time", names, path, "a time unit (s, ms, us, ns)")
    torque_scale = _lookup(TORQUE_UNITS, units.get("torque"), "torque", names, path, "a torque unit (Nm, mNm, kNm)")
    scales = []
    for role, cpr in (("motor", motor_cpr), ("load", load_cpr)):
        unit = override if override is not None else units.get(role)
        if unit is None:
            scales.append(1.0)
            continue
        try:
            scales.append(unit_scale(unit, cpr, role, names[role], path))
        except LogFormatError as exc:
            other = "load" if role == "motor" else "motor"
            raise LogFormatError(
                path, None, f"{exc.reason} (the {other} channel {names[other]!r} has unit {units.get(other)!r})"
            ) from None
    return time_scale, scales[0], scales[1], torque_scale


def _lookup(
    table: dict[str, float], unit: str | None, role: str, names: dict[str, str], path: str, expected: str
) -> float:
    if unit is None:
        return 1.0
    try:
        return table[unit.strip().lower()]
    except KeyError:
        raise LogFormatError(
            path, None, f"{role} channel {names[role]!r} has unit {unit!r}, expected {expected}"
        ) from None


def open_with(
    path: str, kind: str, reader: Callable[[Any], Any], on_failure: Callable[[BaseException], None] | None = None
) -> tuple[Any, IO[bytes]]:
    """``(reader(file object), file object)`` for the file at ``path``, opened here and closed here if the reader fails.

    A file that is empty or does not start as a ``kind`` file does
    (:func:`~online_backlash.replay.signatures.check_signature`) is refused before the library reads
    it; a library reader that fails on a damaged file (any exception) becomes LogFormatError naming
    the file and saying what is wrong in its terms
    (:func:`~online_backlash.replay.signatures.library_failure`); ``on_failure`` may release what the
    library left behind.
    """
    check_signature(path, kind)
    try:
        stream = open(path, "rb")
    except OSError as exc:
        raise LogFormatError(path, None, f"cannot open: {exc.strerror or exc}") from exc
    try:
        return reader(stream), stream
    except Exception as exc:  # third-party readers raise many types on a damaged file
        stream.close()
        if on_failure is not None:
            on_failure(exc)
        raise library_failure(path, kind, exc) from exc


def reads_torque(mapped: frozenset[str]) -> bool:
    """Whether a log reads a torque column: where no column map is given (the default names, ``torque``
    among them), or where the map names the torque role. A map of the other roles alone leaves every
    column out that it does not name, a column that happens to be called ``torque`` too (issue 27)."""
    return not mapped or "torque" in mapped


def torque_like(names: Iterable[str], used: str | None) -> tuple[str, ...]:
    """The names among ``names`` that look like a torque (:data:`TORQUE_LIKE`), but ``used``."""
    return tuple(n for n in names if n != used and TORQUE_LIKE.search(n))


def role_names(columns: dict[str, str] | None) -> dict[str, str]:
    """Role -> column/channel name, unmapped roles named after themselves; unknown roles raise."""
    unknown = set(columns or {}) - set(ROLES)
    if unknown:
        raise InvalidParameterError(f"unknown column roles {sorted(unknown)}; roles are {ROLES}")
    return {role: (columns or {}).get(role, role) for role in ROLES}


def missing_channel(path: str, role: str, name: str, available: Iterable[str], kind: str = "channel") -> LogFormatError:
    """The error for a ``role`` mapped to a ``name`` the file does not hold, listing the closest names."""
    available = list(available)
    close = difflib.get_close_matches(name, available, n=5, cutoff=0.5)
    hint = f"closest: {close}" if close else f"{len(available)} {kind}s, e.g. {available[:8]}"
    return LogFormatError(
        path, None, f"no {kind} {name!r} for {role} ({hint}); map it with columns=/--columns {role}=NAME"
    )


@dataclass(frozen=True)
class ChannelInfo:
    """One column or channel of a file, as ``inspect`` lists it.

    ``group`` is the MDF channel group index or TDMS group name (None for flat tables), ``unit``
    the unit string (None where the format has none), ``samples`` the number of values,
    ``rate_hz`` the sampling rate where the file states or implies it, and ``shape`` the array's
    shape as its author sees it (MATLAB and HDF5 variables: ``20000x1``).
    """

    name: str
    dtype: str
    samples: int | None
    group: str | int | None = None
    unit: str | None = None
    rate_hz: float | None = None
    shape: str | None = None


class Resampler:
    """A channel on its own time base, read forward in blocks, evaluated at another channel's times.

    ``blocks`` yields ``(time_s, values)`` arrays in time order. :meth:`at` interpolates linearly
    and says which times lie inside the channel's recorded span; times must be asked for in
    increasing order (memory stays bounded by one block).
    """

    def __init__(self, blocks: Iterator[tuple[np.ndarray, np.ndarray]], path: str, channel: str) -> None:
        self._blocks = blocks
        self._path = path
        self._channel = channel
        self._time = np.empty(0)
        self._values = np.empty(0)
        self._read = 0

    def _extend(self) -> bool:
        block = next(self._blocks, None)
        if block is None:
            return False
        time, values = (np.asarray(a, dtype=float) for a in block)
        joined = np.concatenate((self._time[-1:], time))
        steps = np.diff(joined)
        if np.any(~(steps >= 0)):
            bad = int(np.flatnonzero(~(steps >= 0))[0])
            row = self._read + bad - (1 if self._time.size else 0)
            raise LogFormatError(self._path, row, f"time of channel {self._channel!r} goes backwards or is not finite")
        self._read += time.size
        self._time = np.concatenate((self._time, time))
        self._values = np.concatenate((self._values, values))
        return True

    def at(self, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values at ``time_s`` (linear interpolation) and a mask of the times inside the channel's span."""
        if time_s.size == 0:
            return np.empty(0), np.zeros(0, bool)
        while (self._time.size == 0 or self._time[-1] < time_s[-1]) and self._extend():
            pass
        if self._time.size == 0:
            return np.full(time_s.size, np.nan), np.zeros(time_s.size, bool)
        inside = (time_s >= self._time[0]) & (time_s <= self._time[-1])
        values = np.interp(time_s, self._time, self._values)
        keep = max(int(np.searchsorted(self._time, time_s[-1], side="right")) - 1, 0)
        self._time, self._values = self._time[keep:], self._values[keep:]
        return values, inside


class TabularSource(SampleSource):
    """Base of the column/channel readers: role names, skip-bad policy and block validation.

    A subclass sets ``path``, ``columns`` (role -> name), ``skip_bad``, ``counters`` and
    ``nominal_period_s`` and calls :meth:`_validate` on each block of parsed values.
    """

    path: str
    columns: dict[str, str]
    mapped: frozenset[str]
    skip_bad: bool
    nominal_period_s: float | None
    #: Nominal sample period, seconds, for gap detection (None: learnt from the first steps).
    period_s: float | None = None
    #: Torque-like columns or channels the file holds but that are not read (:func:`torque_like`), once it is read.
    unused_torque_columns: tuple[str, ...] = ()

    def _bad(self, line: int, reason: str) -> None:
        if not self.skip_bad:
            raise LogFormatError(self.path, line, reason)
        self.counters.corrupt += 1

    def _validate(
        self,
        values: np.ndarray,
        numbers: np.ndarray,
        has_torque: bool,
        last_time: float,
        scales: tuple[float, float] | None = None,
    ) -> tuple[SampleChunk, float]:
        """:meth:`_validate_columns` of a 2-D block whose columns are time, motor, load[, torque]."""
        width = 4 if has_torque else 3
        return self._validate_columns([values[:, i] for i in range(width)], numbers, last_time, scales)

    def _validate_columns(
        self,
        columns: list[np.ndarray],
        numbers: np.ndarray | int,
        last_time: float,
        scales: tuple[float, float] | None = None,
        copy: bool = False,
    ) -> tuple[SampleChunk, float]:
        """Drop (or raise on) non-finite rows and backward times; mark gaps; scale the angles to degrees.

        ``columns`` are the arrays time (s), motor, load[, torque (N m)] of one block; ``numbers``
        each row's line or row number for messages (an int: the first row's, the others
        following it); ``scales`` the motor and load degrees per unit (default: the attributes
        ``motor_scale``/``load_scale``). Returns the block and the last kept time. The checks
        are one compiled pass over the block (:func:`~online_backlash.replay.block_checks.screen_block`);
        a clean block (all finite, in time order) is passed on without copies where its columns
        already are contiguous float64 in degrees, unless ``copy`` (the columns' memory is reused).
        """
        scales = scales if scales is not None else (self.motor_scale, self.load_scale)  # type: ignore[attr-defined]
        columns = [np.asarray(c, dtype=float) for c in columns]
        limits = MAX_ANGLE_DEG / abs(scales[0]), MAX_ANGLE_DEG / abs(scales[1])
        size = columns[0].size
        # passed on as they are when clean, contiguous and in degrees; else the checking pass writes the samples
        as_they_are = not copy and scales == (1.0, 1.0) and all(c.flags.c_contiguous for c in columns)
        out = None if as_they_are else np.empty((4, size))
        found = screen_block(columns, limits, last_time, scales, out)
        if found.bad:
            self._reject(columns, numbers, found)  # raises, unless skip_bad
            if out is None:
                out = np.empty((4, size))
                screen_block(columns, limits, last_time, scales, out)
        if out is None:
            time, motor, load = columns[:3]
            torque = columns[3] if len(columns) > 3 else np.full(size, np.nan)
        else:
            time, motor, load, torque = out[:, : size - found.bad]
        if last_time == -math.inf:  # a new pass over the file: the one gap rule of every source, from the start
            self._gap_rule = GapDetector(None, self.period_s)
            self._repeated_times = 0
            self._first_time = float(time[0]) if time.size else math.nan
            self._warn_of_radians({"motor": motor, "load": load}, scales)
        elif math.isnan(self._first_time) and time.size:
            self._first_time = float(time[0])
        if time.size:
            self._repeated_times += found.repeated
            self._last_number = int(numbers + found.last_good if isinstance(numbers, int) else numbers[found.last_good])
        after_gap, gaps = self._gap_rule.check_times(time)
        for gap in gaps:
            self.counters.report_gap(gap)
        self.nominal_period_s = self._gap_rule.period_s
        self.counters.samples += time.size
        self._pass_last_time = found.last_time
        return SampleChunk(
            time_s=time, motor_deg=motor, load_deg=load, torque_Nm=torque, after_gap=after_gap
        ), found.last_time

    def _on_motor_time(
        self,
        columns: dict[str, np.ndarray],
        foreign: dict[str, Resampler],
        first: int,
        last_time: float,
        scales: tuple[float, float, float, float],
    ) -> tuple[SampleChunk, float]:
        """One block on the motor's time base (``columns["time"]``, seconds, from row ``first``): the roles recorded
        on other time bases (``foreign``) interpolated onto it, the motor samples outside their span counted in
        ``counters.skipped`` and left out, then :meth:`_validate_columns` (``scales``: :func:`channel_scales`)."""
        time = columns["time"]
        inside = np.ones(time.size, bool)
        for role, resampler in foreign.items():
            columns[role], ok = resampler.at(time)
            inside &= ok
        self.counters.frames += time.size
        self.counters.skipped += int(np.count_nonzero(~inside))
        torque = [columns["torque"] * scales[3]] if "torque" in columns else []
        arrays = [time, columns["motor"], columns["load"], *torque]
        numbers: np.ndarray | int = first
        if not inside.all():
            arrays, numbers = [a[inside] for a in arrays], np.flatnonzero(inside) + first
        return self._validate_columns(arrays, numbers, last_time, scales[1:3])

    def _warn_of_radians(self, angles_deg: dict[str, np.ndarray], scales: tuple[float, float]) -> None:
        """One BacklashWarning when angles read as degrees as they are (scale 1) step on a grid of radians
        (:func:`~online_backlash.replay.unit_hints.radian_counts`), naming the columns and ``--units rad``."""
        as_read = [(role, values) for (role, values), scale in zip(angles_deg.items(), scales) if scale == 1.0]
        found = {role: radian_counts(values) for role, values in as_read}
        named = [f"{role} {self.columns[role]!r} by 2 pi/{n}" for role, n in found.items() if n is not None]
        if named:
            warnings.warn(
                f"{self.path}: the angles step by a grid of radians ({', '.join(named)}: an encoder's counts "
                "written in radians), not of degrees, but are read as degrees: give --units rad",
                BacklashWarning,
                stacklevel=2,
            )

    def _warn_of_named_units(self, read_as: str | None) -> None:
        """One BacklashWarning per motor or load column whose name states a unit other than ``read_as``
        (:func:`~online_backlash.replay.unit_hints.unit_mismatch`: ``motor_counts`` read as degrees)."""
        for role in ("motor", "load"):
            named = unit_mismatch(self.columns[role], read_as)
            if named is not None:
                fix = f"--units counts --{role}-cpr N" if named in COUNT_UNITS else f"--units {named}"
                warnings.warn(
                    f"{self.path}: column {self.columns[role]!r} names its unit {named!r}, but the {role} angles are "
                    f"read as {read_as or 'deg'}: give {fix}",
                    BacklashWarning,
                    stacklevel=2,
                )

    def _reject(self, columns: list[np.ndarray], numbers: np.ndarray | int, found: Screened) -> None:
        """The bad rows :func:`~online_backlash.replay.block_checks.screen_block` found: LogFormatError naming the first
        (by value before by time, as row-by-row checks find them), or with ``skip_bad`` counted in
        ``counters.corrupt``."""
        if self.skip_bad:
            self.counters.corrupt += found.bad
            return
        if found.first_value >= 0:
            row = found.first_value
            bad = [f"{r} {self.columns[r]!r}" for r, c in zip(ROLES, columns) if not math.isfinite(c[row])]
            if bad:
                reason = f"non-finite value in {', '.join(bad)}"
            else:
                names = f"motor {self.columns['motor']!r} or load {self.columns['load']!r}"
                reason = f"angle beyond {MAX_ANGLE_DEG:g} deg in {names}: check the units"
        else:
            row = found.first_backwards
            went = f"({columns[0][row]:g} s after {found.backwards_from:g} s)"
            reason = f"time goes backwards in {self.columns['time']!r} {went}"
        raise LogFormatError(self.path, int(numbers + row if isinstance(numbers, int) else numbers[row]), reason)

    def _end_of_pass(self, last_time: float) -> None:
        """After the last block: LogFormatError if the time column never advanced (two samples or more,
        all at one time), and one BacklashWarning counting the samples that repeat the previous time."""
        samples = self.counters.samples
        if samples < 2:
            return
        name = self.columns["time"]
        if last_time == self._first_time:
            raise LogFormatError(
                self.path,
                self._last_number,
                f"time column {name!r} never advances: all {samples} samples at {last_time:g} s; map the real time "
                "with --columns time=NAME",
            )
        if self._repeated_times:
            warnings.warn(
                f"{self.path}: {self._repeated_times} of {samples} samples repeat the previous sample's time in "
                f"{name!r} "
                "(duplicated timestamps; kept)",
                BacklashWarning,
                stacklevel=2,
            )


class MeasurementLog(TabularSource):
    """Base of the measurement-file readers (MDF, TDMS, Parquet/Arrow): their settings, open/close and blocks.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    columns : dict, optional
        Role -> channel or column name for ``motor``, ``load``, and the optional ``torque`` and
        ``time`` (each format says what an unmapped ``time`` means).
    units : str, optional
        Overrides the unit of the motor and load channels (``deg``, ``rad``, ``rev``, ``counts``, ...).
    motor_cpr, load_cpr : float, optional
        Counts per revolution of channels in encoder counts.
    skip_bad : bool
        Count and skip non-finite or out-of-order samples instead of raising.
    block_rows : int
        Samples read at once, where the format reads by rows (memory stays bounded by it).

    A subclass writes :meth:`_open` (open the file; returns what :meth:`close` must close, in
    closing order) and :meth:`_read` (the validated blocks).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        columns: dict[str, str] | None = None,
        units: str | None = None,
        motor_cpr: float | None = None,
        load_cpr: float | None = None,
        skip_bad: bool = False,
        block_rows: int = 65536,
    ) -> None:
        self.path = os.fspath(path)
        self.columns = role_names(columns)
        self.mapped = frozenset(columns or {})
        self.units = units
        self.motor_cpr = motor_cpr
        self.load_cpr = load_cpr
        self.skip_bad = skip_bad
        self.block_rows = int(block_rows)
        self.counters = StreamCounters()
        self.nominal_period_s: float | None = None
        self._handles: tuple[Any, ...] = ()

    @abstractmethod
    def _open(self) -> tuple[Any, ...]:
        """Open the file; return the objects to close, in closing order."""

    @abstractmethod
    def _read(self) -> Iterator[SampleChunk]:
        """The validated blocks of the open file (counters reset)."""

    def close(self) -> None:
        """Close the file, if open."""
        handles, self._handles = self._handles, ()
        for handle in handles:
            handle.close()

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """Validated blocks of samples (seconds, degrees, N m), at most ``max_samples`` each; at the end of
        the pass a time that never advanced raises and repeated times warn, as in CSV logs."""
        self.close()
        self._handles = self._open()
        self._pass_last_time = -math.inf
        try:
            yield from rechunk(self._read(), max_samples)
            self._end_of_pass(self._pass_last_time)  # a whole pass: a time that never advances, repeated times
        finally:
            self.close()

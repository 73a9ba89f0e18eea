"""Recorded CSV logs as a sample source.

Format: a header row naming the columns, then one row per sample. The default names are
``time`` (seconds), ``motor`` and ``load`` (angles, degrees unless ``units`` says otherwise) and
an optional ``torque`` (N m); other columns are ignored. Real logs name their columns
otherwise: ``columns={"time": "time_s", "motor": "motor_counts", "load": "spindle_counts"}``
maps them.

Rows are parsed in blocks by pandas' C parser (the fast path); a block that fails is
re-read row by row with the :mod:`csv` module to name the exact line. A malformed row, a
non-finite value or a time that goes backwards raises :class:`LogFormatError` naming the file
and line, or, with ``skip_bad=True``, is counted in ``counters.corrupt`` and skipped. A time
step longer than three nominal periods is reported as a gap (``counters.gap_log``) and the next
sample carries ``after_gap=True``. ``.csv.gz`` files are read transparently.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import os
import operator
from itertools import islice, repeat
from typing import Iterator

import numpy as np

from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.stream import GAP_PERIODS, Gap, Sample, SampleChunk, SampleSource, StreamCounters

ROLES = ("time", "motor", "load", "torque")
_REQUIRED = ("time", "motor", "load")
_UNITS = ("deg", "rad", "counts")


def angle_scale(units: str, cpr: float | None, which: str) -> float:
    """Degrees per unit of a motor or load column (``which`` names it in errors)."""
    if units not in _UNITS:
        raise InvalidParameterError(f"units must be one of {_UNITS}, got {units!r}")
    if units == "deg":
        return 1.0
    if units == "rad":
        return 180.0 / math.pi
    if cpr is None or not math.isfinite(cpr) or cpr <= 0:
        raise InvalidParameterError(f"units='counts' needs a positive {which}_cpr (counts per revolution), got {cpr!r}")
    return 360.0 / cpr


class CsvLog(SampleSource):
    """A CSV log replayed as a stream of :class:`~online_backlash.stream.Sample`.

    Parameters
    ----------
    path : str or os.PathLike
        The log (``.csv`` or ``.csv.gz``).
    columns : dict, optional
        Role -> column name for the roles ``time``, ``motor``, ``load`` and ``torque``;
        unmapped roles use their own name.
    units : {"deg", "rad", "counts"}
        Unit of the motor and load columns. Samples are always in degrees.
    motor_cpr, load_cpr : float, optional
        Counts per revolution of the motor and load encoders (with ``units="counts"``); the
        motor angle stays on the motor shaft, the ratio is applied by the consumer.
    skip_bad : bool
        Count and skip bad rows instead of raising.
    block_rows : int
        Rows parsed at once (memory stays bounded by it).

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts data rows read; ``frames == samples + corrupt`` at the end.
    nominal_period_s : float or None
        The median time step of the first block, seconds.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        columns: dict[str, str] | None = None,
        units: str = "deg",
        motor_cpr: float | None = None,
        load_cpr: float | None = None,
        skip_bad: bool = False,
        block_rows: int = 65536,
    ) -> None:
        self.path = os.fspath(path)
        unknown = set(columns or {}) - set(ROLES)
        if unknown:
            raise InvalidParameterError(f"unknown column roles {sorted(unknown)}; roles are {ROLES}")
        self.columns = {role: (columns or {}).get(role, role) for role in ROLES}
        self.motor_scale = angle_scale(units, motor_cpr, "motor")
        self.load_scale = angle_scale(units, load_cpr, "load")
        self.skip_bad = skip_bad
        self.block_rows = int(block_rows)
        self.counters = StreamCounters()
        self.nominal_period_s: float | None = None
        self._file: io.TextIOBase | None = None

    # -- context manager / source protocol -------------------------------------------------
    def __enter__(self) -> "CsvLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file, if open."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def __iter__(self) -> Iterator[Sample]:
        for chunk in self.iter_chunks():
            torque = chunk.torque_Nm
            for i in range(len(chunk)):
                yield Sample(
                    float(chunk.time_s[i]),
                    float(chunk.motor_deg[i]),
                    float(chunk.load_deg[i]),
                    None if math.isnan(torque[i]) else float(torque[i]),
                    None,
                    bool(chunk.after_gap[i]),
                )

    # -- reading ---------------------------------------------------------------------------
    def _open(self) -> io.TextIOBase:
        try:
            if self.path.endswith(".gz"):
                return io.TextIOWrapper(gzip.open(self.path, "rb"), encoding="utf-8", newline="")
            return open(self.path, encoding="utf-8", newline="")
        except OSError as exc:
            raise LogFormatError(self.path, None, f"cannot open: {exc.strerror or exc}") from exc

    def _header(self, f: io.TextIOBase) -> tuple[list[int], bool]:
        line = f.readline()
        if not line.strip():
            raise LogFormatError(self.path, 1, "empty file: expected a header row naming the columns")
        names = [n.strip() for n in next(csv.reader([line]))]
        missing = [self.columns[r] for r in _REQUIRED if self.columns[r] not in names]
        if missing:
            raise LogFormatError(self.path, 1, f"header has no column {missing} (columns: {names}); map them with columns=/--columns")
        has_torque = self.columns["torque"] in names
        roles = _REQUIRED + (("torque",) if has_torque else ())
        self._n_columns = len(names)
        return [names.index(self.columns[r]) for r in roles], has_torque

    def iter_chunks(self) -> Iterator[SampleChunk]:
        """Yield validated blocks of samples (degrees, seconds, N m); the fast path for ``learn_many``."""
        self.close()
        self._file = f = self._open()
        try:
            yield from self._read_blocks(f)
        finally:
            self.close()

    def _read_blocks(self, f: io.TextIOBase) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        try:
            usecols, has_torque = self._header(f)
        except UnicodeDecodeError as exc:
            raise LogFormatError(self.path, 1, f"not a text CSV file ({exc.reason})") from exc
        line_no = 1  # lines consumed so far
        last_time = -math.inf
        while True:
            try:
                lines = list(islice(f, self.block_rows))
            except UnicodeDecodeError as exc:
                raise LogFormatError(self.path, line_no + 1, f"not UTF-8 text ({exc.reason})") from exc
            if not lines:
                break
            values, line_numbers = self._parse_block(lines, line_no, usecols)
            line_no += len(lines)
            chunk, last_time = self._validate(values, line_numbers, has_torque, last_time)
            if len(chunk):
                yield chunk

    def _parse_block(self, lines: list[str], first: int, usecols: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Parse rows to a float array; returns it with each row's 1-based line number."""
        numbers = np.arange(first + 1, first + 1 + len(lines))
        # per-line checks through map (C-level loops; a list comprehension here dominated the read time)
        blank = np.fromiter(map(operator.not_, map(str.strip, lines)), bool, len(lines))
        if blank.all():  # nothing to parse
            return np.empty((0, len(usecols))), numbers[:0]
        try:
            values = _read_block("".join(lines), usecols)
        except ValueError:  # pandas' ParserError is a ValueError too
            return self._parse_rows(lines, numbers, usecols)
        commas = np.fromiter(map(str.count, lines, repeat(",")), np.int64, len(lines))
        row_ok = commas[~blank] == self._n_columns - 1
        if values.shape[0] == (~blank).sum() and row_ok.all() and not np.isnan(values).any():
            self.counters.frames += values.shape[0]
            return values, numbers[~blank]
        # a short row, an empty field or a literal NaN: re-read row by row for the exact reason
        return self._parse_rows(lines, numbers, usecols)

    def _parse_rows(self, lines: list[str], numbers: np.ndarray, usecols: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """The slow path: row by row, to name the bad line."""
        rows, kept = [], []
        for line, number in zip(lines, numbers):
            if not line.strip():
                continue
            self.counters.frames += 1
            fields = next(csv.reader([line]))
            if len(fields) != self._n_columns:
                self._bad(int(number), f"expected {self._n_columns} columns, got {len(fields)}")
                continue
            try:
                rows.append([float(fields[i]) for i in usecols])
            except ValueError:
                self._bad(int(number), f"not a number in columns {[fields[i] for i in usecols]}")
                continue
            kept.append(number)
        return np.array(rows, dtype=float).reshape(-1, len(usecols)), np.array(kept, dtype=int)

    def _bad(self, line: int, reason: str) -> None:
        if not self.skip_bad:
            raise LogFormatError(self.path, line, reason)
        self.counters.corrupt += 1

    def _validate(
        self, values: np.ndarray, numbers: np.ndarray, has_torque: bool, last_time: float
    ) -> tuple[SampleChunk, float]:
        """Drop (or raise on) non-finite rows and backward times; mark gaps."""
        finite = np.all(np.isfinite(values), axis=1)
        keep = finite.copy()
        for i in np.flatnonzero(~finite):
            self._bad(int(numbers[i]), "non-finite value")
        time = values[:, 0]
        # a time that goes backwards, relative to the last kept time (the loop only when some does)
        prev = last_time
        kept = time[keep]
        in_order = kept.size == 0 or (kept[0] >= last_time and bool(np.all(np.diff(kept) >= 0)))
        for i in range(0 if in_order else time.size):
            if not keep[i]:
                continue
            if time[i] < prev:
                self._bad(int(numbers[i]), f"time goes backwards ({time[i]:g} s after {prev:g} s)")
                keep[i] = False
                continue
            prev = time[i]
        values = values[keep]
        time = values[:, 0]
        dt = np.diff(np.concatenate(([last_time], time))) if time.size else np.empty(0)
        if self.nominal_period_s is None and time.size > 1:
            steps = np.diff(time)
            steps = steps[steps > 0]
            self.nominal_period_s = float(np.median(steps)) if steps.size else None
        after_gap = np.zeros(time.size, dtype=bool)
        if self.nominal_period_s:
            limit = GAP_PERIODS * self.nominal_period_s
            for i in np.flatnonzero(np.isfinite(dt) & (dt > limit)):
                after_gap[i] = True
                missing = int(round(dt[i] / self.nominal_period_s)) - 1
                self.counters.report_gap(Gap(float(time[i]), float(dt[i]), missing))
        self.counters.samples += time.size
        torque = values[:, 3] if has_torque else np.full(time.size, np.nan)
        chunk = SampleChunk(
            time_s=np.ascontiguousarray(time),
            motor_deg=values[:, 1] * self.motor_scale,
            load_deg=values[:, 2] * self.load_scale,
            torque_Nm=np.ascontiguousarray(torque),
            after_gap=after_gap,
        )
        return chunk, (float(time[-1]) if time.size else last_time)


def _read_block(text: str, usecols: list[int]) -> np.ndarray:
    """Parse a block of CSV rows (no header) to floats with pandas' C parser, columns in ``usecols`` order.

    Raises ValueError on anything that is not a number.
    """
    import pandas as pd  # imported here: only reading a log needs it

    frame = pd.read_csv(
        io.StringIO(text), header=None, usecols=usecols, dtype=float, engine="c", skip_blank_lines=True
    )
    return frame[usecols].to_numpy(dtype=float)


def read_csv_arrays(path: str | os.PathLike[str], **options) -> SampleChunk:
    """Read a whole CSV log into one :class:`SampleChunk` (for batch fits of logs that fit in memory)."""
    with CsvLog(path, **options) as log:
        chunks = list(log.iter_chunks())
    if not chunks:
        raise LogFormatError(os.fspath(path), None, "no data rows")
    return SampleChunk(*(np.concatenate([getattr(c, f) for c in chunks]) for f in ("time_s", "motor_deg", "load_deg", "torque_Nm", "after_gap")))

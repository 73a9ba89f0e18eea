"""Recorded CSV logs as a sample source.

Format: a header row naming the columns, then one row per sample. The default names are
``time`` (seconds), ``motor`` and ``load`` (angles, degrees unless ``units`` says otherwise) and
an optional ``torque`` (N m); other columns are ignored. Real logs name their columns
otherwise: ``columns={"time": "time_s", "motor": "motor_counts", "load": "spindle_counts"}``
maps them.

Rows are parsed in blocks by pandas' C parser (the fast path); a block that fails is
re-read row by row with the :mod:`csv` module to name the exact line. A malformed row, a
non-finite value or a time that goes backwards raises :class:`LogFormatError` naming the file
and line, or, with ``skip_bad=True``, is counted in ``counters.corrupt`` and skipped. Gaps follow
the rule of every source (:class:`~online_backlash.codecs.gaps.GapDetector`): a time step longer
than three nominal periods (given as ``period_s``, or learnt as the median of the first steps) is
reported as a gap (``counters.gap_log``) and the next sample carries ``after_gap=True``.
``.csv.gz`` files are read transparently.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import operator
import os
from collections.abc import Iterator
from itertools import islice, repeat
from typing import Any

import numpy as np

from online_backlash.codecs.gaps import GapDetector
from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleChunk, StreamCounters, read_all, rechunk

from .tabular import REQUIRED as _REQUIRED
from .tabular import TabularSource, angle_scale, role_names


class CsvLog(TabularSource):
    """A CSV log replayed as a :class:`~online_backlash.stream.SampleSource`.

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
        Rows parsed at once (memory stays bounded by it; the natural block of :meth:`iter_chunks`).
    period_s : float, optional
        Nominal sample period, seconds, for gap detection (None: learnt from the first steps).

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts data rows read; ``frames == samples + corrupt`` at the end.
    nominal_period_s : float or None
        The nominal sample period of the gap rule, seconds: ``period_s``, or learnt while reading.
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
        period_s: float | None = None,
    ) -> None:
        self.path = os.fspath(path)
        self.columns = role_names(columns)
        self.motor_scale = angle_scale(units, motor_cpr, "motor")
        self.load_scale = angle_scale(units, load_cpr, "load")
        self.skip_bad = skip_bad
        self.block_rows = int(block_rows)
        self.period_s = GapDetector(None, period_s).period_s  # validated
        self.nominal_period_s: float | None = period_s
        self.counters = StreamCounters()
        self._file: io.TextIOBase | None = None

    def close(self) -> None:
        """Close the file, if open."""
        if self._file is not None:
            self._file.close()
            self._file = None

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

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """Validated blocks of samples (seconds, degrees, N m): one per ``block_rows`` rows read,
        or of ``max_samples`` each (the last one shorter); the fast path for ``learn_many``."""
        return rechunk(self._read(), max_samples)

    def _read(self) -> Iterator[SampleChunk]:
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


def _read_block(text: str, usecols: list[int]) -> np.ndarray:
    """Parse a block of CSV rows (no header) to floats with pandas' C parser, columns in ``usecols`` order.

    Raises ValueError on anything that is not a number.
    """
    import pandas as pd  # imported here: only reading a log needs it

    frame = pd.read_csv(
        io.StringIO(text), header=None, usecols=usecols, dtype=float, engine="c", skip_blank_lines=True
    )
    return frame[usecols].to_numpy(dtype=float)


def read_csv_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole CSV log into one :class:`SampleChunk` (for batch fits of logs that fit in memory)."""
    return read_all(CsvLog(path, **options), path, "no data rows")

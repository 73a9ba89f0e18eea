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
``.csv.gz`` files are read transparently; a truncated or damaged one raises LogFormatError naming
the line where it ends.

The dialect is sniffed from the first few KB (:func:`sniff_dialect`), as people write CSV: a
UTF-8 byte-order mark (Excel's "CSV UTF-8"), ``,``, ``;``, tab or ``|`` as separator, a decimal
comma with ``;`` (German Excel, ``pandas.to_csv(sep=";", decimal=",")``), quoted cells and CRLF
line ends. ``delimiter=`` and ``decimal=`` override the guess.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import operator
import os
import re
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import islice, repeat
from typing import Any

import numpy as np

from online_backlash.codecs.gaps import GapDetector
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.stream import SampleChunk, StreamCounters, read_all, rechunk

from .tabular import REQUIRED as _REQUIRED
from .tabular import TabularSource, angle_scale, reads_torque, role_names, torque_like

#: Separators the sniffer chooses from.
DELIMITERS = ",;\t|"
#: Decimal marks a CSV may use.
DECIMALS = (".", ",")
#: Characters read to sniff the dialect.
SNIFF_CHARS = 4096
_COMMA_NUMBER = re.compile(r"^\s*[-+]?\d*,\d+(?:[eE][-+]?\d+)?\s*$")
_POINT_NUMBER = re.compile(r"^\s*[-+]?\d*\.\d+(?:[eE][-+]?\d+)?\s*$")
#: What reading a file that is not UTF-8 text, or a damaged or truncated ``.gz``, raises (BadGzipFile is an OSError).
UNREADABLE = (UnicodeDecodeError, EOFError, OSError, zlib.error)


def unreadable(path: str, line: int, exc: Exception) -> LogFormatError:
    """The error for a file that stops being readable text after ``line - 1`` lines were read.

    A bad UTF-8 byte is named by its own line: the decoder fails on a block of bytes that starts
    within the next line (the text before it holds no line end), and says where in it.
    """
    if isinstance(exc, UnicodeDecodeError):
        line += bytes(exc.object[: exc.start]).count(b"\n")
        return LogFormatError(path, line, f"not a text CSV file: not UTF-8 ({exc.reason})")
    return LogFormatError(path, line, f"damaged or truncated file: it ends here ({type(exc).__name__}: {exc})")


@dataclass(frozen=True)
class CsvDialect:
    """How a CSV file is written: its field ``delimiter`` and its ``decimal`` mark (quotes are ``"``)."""

    delimiter: str = ","
    decimal: str = "."


def check_dialect(delimiter: str | None, decimal: str | None) -> None:
    """Raise InvalidParameterError unless ``delimiter`` (one character) and ``decimal`` (``.`` or ``,``) can be used."""
    if delimiter is not None and (len(delimiter) != 1 or delimiter in '"\r\n' or delimiter.isalnum() or delimiter in "+-."):
        raise InvalidParameterError(f"delimiter must be one character such as , ; | or a tab, not a quote, sign, point or letter; got {delimiter!r}")
    if decimal is not None and decimal not in DECIMALS:
        raise InvalidParameterError(f"decimal must be one of {DECIMALS}, got {decimal!r}")
    if delimiter is not None and delimiter == decimal:
        raise InvalidParameterError(f"delimiter and decimal mark are both {delimiter!r}")


def sniff_dialect(sample: str, delimiter: str | None = None, decimal: str | None = None) -> CsvDialect:
    r"""The dialect of a CSV file from its first characters ``sample`` (header row first).

    The separator is :class:`csv.Sniffer`'s choice among :data:`DELIMITERS` (or, when it cannot
    tell, the one the header row holds most of; ``,`` if none); the decimal mark is ``,`` when
    the separator is not ``,`` and the data cells hold more numbers written ``1,5`` than ``1.5``.
    ``delimiter`` and ``decimal`` override the guess.

    Examples
    --------
    >>> sniff_dialect("time;motor;load\n0,001;1,5;2,5\n")
    CsvDialect(delimiter=';', decimal=',')
    >>> sniff_dialect('"time","motor","load"\r\n"0.001","1.5","2.5"\r\n')
    CsvDialect(delimiter=',', decimal='.')
    """
    check_dialect(delimiter, decimal)
    lines = sample.splitlines()
    if len(sample) >= SNIFF_CHARS and len(lines) > 2:
        lines = lines[:-1]  # the last line may be cut
    if delimiter is None:
        try:
            delimiter = csv.Sniffer().sniff("\n".join(lines), delimiters=DELIMITERS).delimiter
        except csv.Error:
            header = lines[0] if lines else ""
            delimiter = max(DELIMITERS, key=header.count) if any(d in header for d in DELIMITERS) else ","
    if decimal is None:
        decimal = "."
        if delimiter != ",":
            cells = [cell for row in csv.reader(lines[1:], delimiter=delimiter) for cell in row]
            commas = sum(1 for cell in cells if _COMMA_NUMBER.match(cell))
            points = sum(1 for cell in cells if _POINT_NUMBER.match(cell))
            decimal = "," if commas > points else "."
    if delimiter == decimal:
        raise InvalidParameterError(f"delimiter and decimal mark are both {delimiter!r}; give --delimiter or --decimal")
    return CsvDialect(delimiter, decimal)


def open_text(path: str) -> io.TextIOWrapper:
    """The CSV file at ``path`` (``.gz`` looked through) as UTF-8 text, a byte-order mark dropped, line ends kept.

    Raises LogFormatError naming the file when it cannot be opened.
    """
    try:
        if path.lower().endswith(".gz"):
            return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="")
        return open(path, encoding="utf-8-sig", newline="")
    except IsADirectoryError as exc:
        raise LogFormatError(path, None, "is a folder, not a CSV file") from exc
    except OSError as exc:
        reason = "no such file or folder" if isinstance(exc, FileNotFoundError) else exc.strerror or str(exc)
        raise LogFormatError(path, None, f"cannot open: {reason}") from exc


def file_dialect(f: io.TextIOBase, path: str, delimiter: str | None = None, decimal: str | None = None) -> CsvDialect:
    """:func:`sniff_dialect` of the open text file ``f`` at its start; ``f`` is rewound to the start."""
    try:
        try:
            sample = f.read(SNIFF_CHARS)
        except UnicodeDecodeError:  # a bad byte somewhere in the first block: the reader names its line later
            f.seek(0)
            sample = f.buffer.read(SNIFF_CHARS).decode("utf-8-sig", "replace")  # type: ignore[attr-defined]
        f.seek(0)
    except UNREADABLE as exc:
        raise unreadable(path, 1, exc) from exc
    return sniff_dialect(sample, delimiter, decimal)


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
    delimiter : str, optional
        Field separator (one character, e.g. ``;`` or a tab); None: sniffed.
    decimal : {".", ","}, optional
        Decimal mark of the numbers; None: sniffed.

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts data rows read; ``frames == samples + corrupt`` at the end.
    nominal_period_s : float or None
        The nominal sample period of the gap rule, seconds: ``period_s``, or learnt while reading.
    dialect : CsvDialect or None
        The separator and decimal mark used (sniffed or given), once reading has begun.
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
        delimiter: str | None = None,
        decimal: str | None = None,
    ) -> None:
        check_dialect(delimiter, decimal)
        self.path = os.fspath(path)
        self.delimiter = delimiter
        self.decimal = decimal
        self.dialect: CsvDialect | None = None
        self._delimiter = delimiter or ","
        self.columns = role_names(columns)
        self.mapped = frozenset(columns or {})
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
    def _header(self, f: io.TextIOBase) -> tuple[list[int], bool]:
        line = f.readline()
        if not line.strip():
            raise LogFormatError(self.path, 1, "empty file: expected a header row naming the columns")
        names = [n.strip() for n in next(csv.reader([line], delimiter=self._delimiter))]
        missing = [self.columns[r] for r in _REQUIRED if self.columns[r] not in names]
        if missing:
            raise LogFormatError(self.path, 1, f"header has no column {missing} (columns: {names}); map them with columns=/--columns")
        has_torque = reads_torque(self.mapped) and self.columns["torque"] in names
        self.unused_torque_columns = torque_like(names, self.columns["torque"] if has_torque else None)
        roles = _REQUIRED + (("torque",) if has_torque else ())
        self._n_columns = len(names)
        return [names.index(self.columns[r]) for r in roles], has_torque

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """Validated blocks of samples (seconds, degrees, N m): one per ``block_rows`` rows read,
        or of ``max_samples`` each (the last one shorter); the fast path for ``learn_many``."""
        return rechunk(self._read(), max_samples)

    def _read(self) -> Iterator[SampleChunk]:
        self.close()
        self._file = f = open_text(self.path)
        try:
            yield from self._read_blocks(f)
        finally:
            self.close()

    def _read_blocks(self, f: io.TextIOBase) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        self.dialect = file_dialect(f, self.path, self.delimiter, self.decimal)
        self._delimiter = self.dialect.delimiter
        try:
            usecols, has_torque = self._header(f)
        except UNREADABLE as exc:
            raise unreadable(self.path, 1, exc) from exc
        line_no = 1  # lines consumed so far
        last_time = -math.inf
        while True:
            lines: list[str] = []
            try:
                lines.extend(islice(f, self.block_rows))  # keeps the lines read before a failure
            except UNREADABLE as exc:
                raise unreadable(self.path, line_no + len(lines) + 1, exc) from exc
            if not lines:
                break
            values, line_numbers = self._parse_block(lines, line_no, usecols)
            line_no += len(lines)
            chunk, last_time = self._validate(values, line_numbers, has_torque, last_time)
            if len(chunk):
                yield chunk
        self._end_of_pass(last_time)

    def _parse_block(self, lines: list[str], first: int, usecols: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Parse rows to a float array; returns it with each row's 1-based line number."""
        numbers = np.arange(first + 1, first + 1 + len(lines))
        # per-line checks through map (C-level loops; a list comprehension here dominated the read time)
        blank = np.fromiter(map(operator.not_, map(str.strip, lines)), bool, len(lines))
        if blank.all():  # nothing to parse
            return np.empty((0, len(usecols))), numbers[:0]
        try:
            values = _read_block("".join(lines), usecols, self.dialect or CsvDialect())
        except ValueError:  # pandas' ParserError is a ValueError too
            return self._parse_rows(lines, numbers, usecols)
        commas = np.fromiter(map(str.count, lines, repeat(self._delimiter)), np.int64, len(lines))
        row_ok = commas[~blank] == self._n_columns - 1
        if values.shape[0] == (~blank).sum() and row_ok.all() and not np.isnan(values).any():
            self.counters.frames += values.shape[0]
            return values, numbers[~blank]
        # a short row, an empty field or a literal NaN: re-read row by row for the exact reason
        return self._parse_rows(lines, numbers, usecols)

    def _parse_rows(self, lines: list[str], numbers: np.ndarray, usecols: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """The slow path: row by row, to name the bad line."""
        rows, kept = [], []
        comma = (self.dialect or CsvDialect()).decimal == ","
        for line, number in zip(lines, numbers):
            if not line.strip():
                continue
            self.counters.frames += 1
            fields = next(csv.reader([line], delimiter=self._delimiter))
            if len(fields) != self._n_columns:
                self._bad(int(number), f"expected {self._n_columns} columns, got {len(fields)}")
                continue
            if comma:
                fields = [field.replace(",", ".") for field in fields]
            try:
                rows.append([float(fields[i]) for i in usecols])
            except ValueError:
                self._bad(int(number), f"not a number in columns {[fields[i] for i in usecols]}")
                continue
            kept.append(number)
        return np.array(rows, dtype=float).reshape(-1, len(usecols)), np.array(kept, dtype=int)


def _read_block(text: str, usecols: list[int], dialect: CsvDialect) -> np.ndarray:
    """Parse a block of CSV rows (no header) to floats with pandas' C parser, columns in ``usecols`` order.

    Raises ValueError on anything that is not a number.
    """
    import pandas as pd  # imported here: only reading a log needs it

    frame = pd.read_csv(
        io.StringIO(text), header=None, usecols=usecols, dtype=float, engine="c", skip_blank_lines=True,
        sep=dialect.delimiter, decimal=dialect.decimal,
    )
    return frame[usecols].to_numpy(dtype=float)


def read_csv_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole CSV log into one :class:`SampleChunk` (for batch fits of logs that fit in memory)."""
    return read_all(CsvLog(path, **options), path, "no data rows")

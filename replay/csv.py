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
line ends. ``delimiter=`` and ``decimal=`` override the guess. Lines before the header that start
with ``#`` (a logger's ``# logger v2.1``) are skipped; ``comment=`` names another character, and with
it a line starting with that character is skipped anywhere in the file.

The text encoding is UTF-8 unless a byte-order mark says UTF-8, UTF-16 (LE or BE, as Excel saves
"Unicode text": tab separated, CRLF, ``.txt``) or UTF-32, or ``encoding=`` names one (``cp1252`` for
a Windows export with ``°`` in its header). A file whose first KB hold NUL bytes is not text and is
refused at once, however large. Delimited text is read from ``.csv``, ``.txt`` and ``.tsv`` files
(:data:`CSV_SUFFIXES`).
"""

from __future__ import annotations

import codecs
import csv
import gzip
import io
import math
import operator
import os
import re
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import islice, repeat
from typing import IO, Any

import numpy as np

from online_backlash.codecs.gaps import GapDetector
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.stream import SampleChunk, StreamCounters, read_all, rechunk

from . import options
from .formats import TABULAR, LogFormat
from .options import Timing
from .summary import FileSummary
from .tabular import REQUIRED as _REQUIRED
from .tabular import ChannelInfo, TabularSource, angle_scale, reads_torque, role_names, torque_like

#: Suffixes of delimited text logs (each also as ``.gz``).
CSV_SUFFIXES = (".csv", ".txt", ".tsv")
#: Separators the sniffer chooses from.
DELIMITERS = ",;\t|"
#: What starts the comment lines skipped before the header when no ``comment`` is given.
SNIFFED_COMMENT = "#"
#: Byte-order marks and the codec that reads past each (UTF-32 before UTF-16: its LE mark starts with UTF-16's).
BYTE_ORDER_MARKS = (
    (codecs.BOM_UTF8, "utf-8-sig"),
    (codecs.BOM_UTF32_LE, "utf-32"),
    (codecs.BOM_UTF32_BE, "utf-32"),
    (codecs.BOM_UTF16_LE, "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16"),
)
#: Decimal marks a CSV may use.
DECIMALS = (".", ",")
#: Lines handed to the parser at once: a block of :attr:`CsvLog.block_rows` is parsed in pieces of this many, as one
#: Python string a line is what a parse holds most of (65,536 at once took the peak RSS of ``estimate`` on 10 M
#: samples to 307 MB, issue 31's bound being 300; ``docs/benchmarks.md``); the blocks, and so what the estimators
#: see, are those of ``block_rows``.
PARSE_ROWS = 32768
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
        byte = bytes(exc.object[exc.start : exc.start + 1])
        utf8 = exc.encoding.startswith("utf-8")
        hint = "; give its encoding with --encoding (e.g. cp1252 for a Windows export)" if utf8 else ""
        what = f"not {_codec_label(exc.encoding)} (byte 0x{byte.hex().upper()}: {exc.reason}){hint}"
        return LogFormatError(path, line, f"not a text CSV file: {what}")
    if isinstance(exc, EOFError):
        detail = "the compressed data stop before the gzip end marker"
    elif isinstance(exc, (zlib.error, gzip.BadGzipFile)):
        detail = f"not valid gzip data: {exc}"
    else:
        detail = f"{type(exc).__name__}: {exc}"
    return LogFormatError(path, line, f"damaged or truncated file: it ends here ({detail})")


def _codec_label(encoding: str) -> str:
    """``UTF-8`` for ``utf-8-sig``, else the codec's own name as Python spells it."""
    name = codecs.lookup(encoding).name
    return "UTF-8" if name.startswith("utf-8") else name


@dataclass(frozen=True)
class CsvDialect:
    """How a CSV file is written: its field ``delimiter``, its ``decimal`` mark (quotes are ``"``), the
    ``comment`` character of the lines skipped anywhere (None: none), and the number of comment lines
    before the header (``preamble``)."""

    delimiter: str = ","
    decimal: str = "."
    comment: str | None = None
    preamble: int = 0


def check_encoding(encoding: str | None) -> None:
    """Raise InvalidParameterError unless ``encoding`` is None or a text codec Python knows (``cp1252``, ``utf-16``)."""
    if encoding is None:
        return
    try:
        info = codecs.lookup(encoding)
    except LookupError:
        raise InvalidParameterError(f"unknown text encoding {encoding!r}; e.g. utf-8, cp1252, utf-16") from None
    if not getattr(info, "_is_text_encoding", True):
        raise InvalidParameterError(f"{encoding!r} is not a text encoding; e.g. utf-8, cp1252, latin-1, utf-16")


def check_dialect(delimiter: str | None, decimal: str | None, comment: str | None = None) -> None:
    """Raise InvalidParameterError unless ``delimiter`` (one character), ``decimal`` (``.`` or ``,``) and ``comment``
    (one character other than them, not a digit, sign or point) can be used."""
    unusable = comment is not None and (len(comment) != 1 or comment.isalnum() or comment in '+-."\r\n')
    if unusable or (comment is not None and comment in (delimiter, decimal)):
        raise InvalidParameterError(
            f"comment must be one character such as # or %, not a digit, letter, sign, point or the separator; "
            f"got {comment!r}"
        )
    if delimiter is not None and (
        len(delimiter) != 1 or delimiter in '"\r\n' or delimiter.isalnum() or delimiter in "+-."
    ):
        raise InvalidParameterError(
            "delimiter must be one character such as , ; | or a tab, not a quote, sign, point or letter; got "
            f"{delimiter!r}"
        )
    if decimal is not None and decimal not in DECIMALS:
        raise InvalidParameterError(f"decimal must be one of {DECIMALS}, got {decimal!r}")
    if delimiter is not None and delimiter == decimal:
        raise InvalidParameterError(f"delimiter and decimal mark are both {delimiter!r}")


def sniff_dialect(
    sample: str, delimiter: str | None = None, decimal: str | None = None, comment: str | None = None
) -> CsvDialect:
    r"""The dialect of a CSV file from its first characters ``sample`` (header row first, after comment lines).

    Lines before the header that start with ``comment`` (None: with :data:`SNIFFED_COMMENT`, ``#``)
    are its ``preamble``. The separator is :class:`csv.Sniffer`'s choice among :data:`DELIMITERS`
    (or, when it cannot tell, the one the header row holds most of; ``,`` if none); the decimal
    mark is ``,`` when the separator is not ``,`` and the data cells hold more numbers written
    ``1,5`` than ``1.5``. ``delimiter`` and ``decimal`` override the guess.

    Examples
    --------
    >>> sniff_dialect("time;motor;load\n0,001;1,5;2,5\n")
    CsvDialect(delimiter=';', decimal=',', comment=None, preamble=0)
    >>> sniff_dialect('"time","motor","load"\r\n"0.001","1.5","2.5"\r\n')
    CsvDialect(delimiter=',', decimal='.', comment=None, preamble=0)
    >>> sniff_dialect("# logger v2.1\n# rig 7\ntime\tmotor\tload\n0.001\t1.5\t2.5\n")
    CsvDialect(delimiter='\t', decimal='.', comment=None, preamble=2)
    """
    check_dialect(delimiter, decimal, comment)
    lines = sample.splitlines()
    if len(sample) >= SNIFF_CHARS and len(lines) > 2:
        lines = lines[:-1]  # the last line may be cut
    marker = comment or SNIFFED_COMMENT
    preamble = next((i for i, line in enumerate(lines) if not line.lstrip().startswith(marker)), len(lines))
    lines = lines[preamble:]
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
    return CsvDialect(delimiter, decimal, comment, preamble)


def text_encoding(head: bytes, path: str, encoding: str | None = None) -> str:
    """The codec of a text file whose first bytes are ``head``: ``encoding`` if given, else the one its byte-order
    mark names (:data:`BYTE_ORDER_MARKS`), else UTF-8; LogFormatError when, with neither, ``head`` holds NUL bytes
    (binary data, or UTF-16 without a mark), so a large binary file is refused before it is read."""
    if encoding is not None:
        return encoding
    for mark, codec in BYTE_ORDER_MARKS:
        if head.startswith(mark):
            return codec
    if b"\0" in head:
        raise LogFormatError(
            path,
            1,
            f"not a text CSV file: NUL bytes in its first {len(head)} bytes (binary data; "
            "UTF-16 text without a byte-order mark needs --encoding utf-16-le or utf-16-be)",
        )
    return "utf-8-sig"


def open_text(path: str, encoding: str | None = None) -> io.TextIOWrapper:
    """The CSV file at ``path`` (``.gz`` looked through) as text (:func:`text_encoding`), a byte-order mark dropped,
    line ends kept.

    Raises LogFormatError naming the file when it cannot be opened or is not text.
    """
    check_encoding(encoding)
    try:
        gz = path.lower().endswith(".gz")
        raw: IO[bytes] = gzip.open(path, "rb") if gz else open(path, "rb")  # type: ignore[assignment]
    except IsADirectoryError as exc:
        raise LogFormatError(path, None, "is a folder, not a CSV file") from exc
    except OSError as exc:
        reason = "no such file or folder" if isinstance(exc, FileNotFoundError) else exc.strerror or str(exc)
        raise LogFormatError(path, None, f"cannot open: {reason}") from exc
    try:
        codec = text_encoding(raw.read(SNIFF_CHARS), path, encoding)
        raw.seek(0)
    except UNREADABLE as exc:
        raw.close()
        raise unreadable(path, 1, exc) from exc
    except BaseException:
        raw.close()
        raise
    return io.TextIOWrapper(raw, encoding=codec, newline="")


def file_dialect(
    f: io.TextIOBase, path: str, delimiter: str | None = None, decimal: str | None = None, comment: str | None = None
) -> CsvDialect:
    """:func:`sniff_dialect` of the open text file ``f`` at its start; ``f`` is left at its header row
    (after the dialect's ``preamble`` of comment lines)."""
    try:
        try:
            sample = f.read(SNIFF_CHARS)
        except UnicodeDecodeError:  # a bad byte somewhere in the first block: the reader names its line later
            f.seek(0)
            raw = f.buffer.read(SNIFF_CHARS)  # type: ignore[attr-defined]
            sample = raw.decode(f.encoding or "utf-8-sig", "replace")
        f.seek(0)
        dialect = sniff_dialect(sample, delimiter, decimal, comment)
        for _ in range(dialect.preamble):
            f.readline()
    except UNREADABLE as exc:
        raise unreadable(path, 1, exc) from exc
    return dialect


def header_names(line: str, dialect: CsvDialect) -> list[str]:
    """The column names of a header row (spaces and a byte-order mark a given encoding left around them dropped)."""
    return [name.strip().lstrip("\ufeff").strip() for name in next(csv.reader([line], delimiter=dialect.delimiter), [])]


def uncommented(lines: Iterable[str], comment: str | None) -> Iterable[str]:
    """``lines`` with each comment line (first non-blank character ``comment``) made blank, so line numbers stay."""
    if comment is None:
        return lines
    return ("\n" if line.lstrip().startswith(comment) else line for line in lines)


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
        Rows read per block (memory stays bounded by it; the natural block of :meth:`iter_chunks`), parsed
        :data:`PARSE_ROWS` at a time.
    period_s : float, optional
        Nominal sample period, seconds, for gap detection (None: learnt from the first steps).
    delimiter : str, optional
        Field separator (one character, e.g. ``;`` or a tab); None: sniffed.
    decimal : {".", ","}, optional
        Decimal mark of the numbers; None: sniffed.
    encoding : str, optional
        Text encoding (``cp1252``, ``utf-16``, ...); None: UTF-8, or what a byte-order mark says.
    comment : str, optional
        A line starting with this character is skipped wherever it is; None: only ``#`` lines before the header.

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
        encoding: str | None = None,
        comment: str | None = None,
    ) -> None:
        check_dialect(delimiter, decimal, comment)
        check_encoding(encoding)
        self.path = os.fspath(path)
        self.delimiter = delimiter
        self.decimal = decimal
        self.encoding = encoding
        self.comment = comment
        self.dialect: CsvDialect | None = None
        self._delimiter = delimiter or ","
        self.columns = role_names(columns)
        self.units = units
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
    def _header(self, f: io.TextIOBase, line_no: int) -> tuple[list[int], bool]:
        line = f.readline()
        if not line.strip():
            raise LogFormatError(self.path, line_no, "empty file: expected a header row naming the columns")
        names = header_names(line, self.dialect or CsvDialect())
        missing = [self.columns[r] for r in _REQUIRED if self.columns[r] not in names]
        if missing:
            reason = f"header has no column {missing} (columns: {names}); map them with columns=/--columns"
            raise LogFormatError(self.path, line_no, reason)
        self._warn_of_named_units(self.units)
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
        self._file = f = open_text(self.path, self.encoding)
        try:
            yield from self._read_blocks(f)
        finally:
            self.close()

    def _read_blocks(self, f: io.TextIOBase) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        self.dialect = file_dialect(f, self.path, self.delimiter, self.decimal, self.comment)
        self._delimiter = self.dialect.delimiter
        line_no = self.dialect.preamble + 1  # lines consumed so far, the header's included
        try:
            usecols, has_torque = self._header(f, line_no)
        except UNREADABLE as exc:
            raise unreadable(self.path, line_no, exc) from exc
        last_time = -math.inf
        while True:
            parsed: list[tuple[np.ndarray, np.ndarray]] = []  # (values, line numbers) of each piece of the block
            read = 0
            while read < self.block_rows:
                lines: list[str] = []
                try:  # keeps the lines read before a failure
                    lines.extend(islice(f, min(PARSE_ROWS, self.block_rows - read)))
                except UNREADABLE as exc:
                    raise unreadable(self.path, line_no + len(lines) + 1, exc) from exc
                if not lines:
                    break
                parsed.append(self._parse_block(list(uncommented(lines, self.comment)), line_no, usecols))
                line_no += len(lines)
                read += len(lines)
            if not read:
                break
            values, line_numbers = (np.concatenate(pieces) for pieces in zip(*parsed))
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

    The rows are handed over as UTF-8 bytes, which the C parser reads as they are: a ``StringIO`` holds
    its text as 4-byte characters and is encoded to UTF-8 by pandas again (13.6 against 5.8 MB at the
    parse's peak for a block of 65,536 rows of the bench's CSV, and a third less CPU). Raises ValueError
    on anything that is not a number.
    """
    import pandas as pd  # imported here: only reading a log needs it

    frame = pd.read_csv(
        io.BytesIO(text.encode("utf-8")),
        encoding="utf-8",
        header=None,
        usecols=usecols,
        dtype=float,
        engine="c",
        skip_blank_lines=True,
        sep=dialect.delimiter,
        decimal=dialect.decimal,
    )
    return frame[usecols].to_numpy(dtype=float)


def read_csv_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole CSV log into one :class:`SampleChunk` (for batch fits of logs that fit in memory)."""
    return read_all(CsvLog(path, **options), path, "no data rows")


#: Rows of a CSV whose cells decide each column's type (``inspect``).
SAMPLE_ROWS = 10000


def describe_columns(
    path: str,
    delimiter: str | None = None,
    decimal: str | None = None,
    comment: str | None = None,
    encoding: str | None = None,
) -> list[ChannelInfo]:
    """The header's columns, each with its type in the first :data:`SAMPLE_ROWS` rows and the file's data row count,
    the file read as the CSV reader reads it (encoding, dialect and comment lines sniffed or given); a row with
    another number of fields than the header raises LogFormatError naming its line."""
    with open_text(path, encoding) as f:
        dialect = file_dialect(f, path, delimiter, decimal, comment)
        consumed = dialect.preamble  # lines before the one being read: the header, then the rows the reader has read
        reader = csv.reader(uncommented(f, comment), delimiter=dialect.delimiter)  # reads on from the header's end
        head: list[list[str]] = []
        rows = 0
        try:
            header = header_names(f.readline(), dialect)
            if not any(header):
                raise LogFormatError(path, consumed + 1, "empty file: expected a header row naming the columns")
            consumed += 1
            for fields in reader:
                if not fields or not any(cell.strip() for cell in fields):
                    continue
                if len(fields) != len(header):
                    reason = f"expected {len(header)} columns, got {len(fields)}"
                    raise LogFormatError(path, consumed + reader.line_num, reason)
                rows += 1
                if len(head) < SAMPLE_ROWS:
                    head.append(fields)
        except UNREADABLE as exc:
            raise unreadable(path, consumed + reader.line_num + 1, exc) from exc
        except csv.Error as exc:
            raise LogFormatError(path, consumed + reader.line_num, f"not a CSV row ({exc})") from exc
    columns = list(zip(*head)) if head else [()] * len(header)
    return [ChannelInfo(name, _column_type(cells, dialect.decimal), rows) for name, cells in zip(header, columns)]


def _column_type(cells: Sequence[str], decimal: str) -> str:
    """``int64``, ``float64`` (numbers with the file's ``decimal`` mark; an empty cell among integers too) or
    ``string``, as pandas would infer the column (``string`` for a header without rows)."""
    filled = [cell.strip() for cell in cells if cell.strip()]
    if not cells:
        return "string"
    try:
        [int(cell) for cell in filled]
        return "int64" if len(filled) == len(cells) else "float64"
    except ValueError:
        pass
    try:
        [float(cell.replace(decimal, ".")) for cell in filled]
        return "float64"
    except ValueError:
        return "string"


def describe(path: str, **dialect: str | None) -> FileSummary:
    """The CSV's columns (``inspect``): :func:`describe_columns` with the ``dialect`` given (else sniffed)."""
    return FileSummary(path, "csv", describe_columns(path, **dialect))


def _describe(path: str, dbc: Any = None, **dialect: str | None) -> FileSummary:
    """:func:`describe` as ``inspect`` calls a format's (a DBC is for CAN logs)."""
    return describe(path, **dialect)


#: CSV and delimited text (also ``.gz``): its format (:data:`~online_backlash.replay.registry.FORMATS`).
CSV = LogFormat(
    "csv",
    CSV_SUFFIXES,
    CsvLog,
    (*TABULAR, Timing, options.CsvDialect),
    _describe,
    title="CSV or delimited text, also .gz; a torque column is used when mapped",
)

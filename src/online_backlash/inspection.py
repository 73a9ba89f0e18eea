"""What a recorded file holds, for ``online-backlash inspect``: columns, channels or CAN IDs.

:func:`inspect_file` lists a CSV's or Parquet/Arrow table's columns (type, rows), an MDF file's
channels (group, unit, rate, samples), a TDMS file's ``group/channel`` s (unit, length, rate),
a MATLAB or HDF5 file's variables (shape, type, length, unit),
or the CAN IDs seen in a CAN log with their counts, rates and (with a DBC) message names, so a
user with 400 channels finds the two to map with ``--columns``. Nothing is printed here.

Examples
--------
>>> import tempfile, os
>>> folder = tempfile.mkdtemp()
>>> path = os.path.join(folder, "run.csv")
>>> with open(path, "w") as f:
...     _ = f.write("time,motor,load\\n0,0,0\\n0.001,0.1,0\\n")
>>> summary = inspect_file(path)
>>> summary.kind, [(c.name, c.dtype, c.samples) for c in summary.channels]
('csv', [('time', 'float64', 2), ('motor', 'float64', 2), ('load', 'int64', 2)])
"""

from __future__ import annotations

import csv
import fnmatch
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from .errors import LogFormatError
from .replay.csv import CSV_SUFFIXES, UNREADABLE, file_dialect, header_names, open_text, uncommented, unreadable
from .replay.measurement import MEASUREMENT_READERS, is_measurement_log
from .replay.paths import file_suffix
from .replay.tabular import ChannelInfo

__all__ = ["CanIdInfo", "ChannelInfo", "FileSummary", "inspect_file"]

#: Rows of a CSV whose cells decide each column's type.
SAMPLE_ROWS = 10000


@dataclass(frozen=True)
class CanIdInfo:
    """One CAN ID seen in a log: ``frames`` frames at ``rate_hz`` (None for a single frame), DBC ``message`` name if known."""

    can_id: int
    extended: bool
    frames: int
    rate_hz: float | None = None
    message: str | None = None

    @property
    def label(self) -> str:
        """The ID as written in DBCs and candump: ``0x123`` or ``0x18FF0001x`` (extended)."""
        return f"0x{self.can_id:08X}x" if self.extended else f"0x{self.can_id:03X}"


@dataclass
class FileSummary:
    """What :func:`inspect_file` found in ``path`` (a file of format ``kind``); ``truncated`` says why a file is
    cut short (None when whole): the counts are then what is readable up to the cut."""

    path: str
    kind: str
    channels: list[ChannelInfo] = field(default_factory=list)
    can_ids: list[CanIdInfo] = field(default_factory=list)
    frames: int | None = None
    truncated: str | None = None

    def matching(self, pattern: str | None) -> FileSummary:
        """The summary restricted to names matching a shell pattern (``*enc*``), case-insensitive; a plain word matches as a substring."""
        if not pattern:
            return self
        glob = pattern.lower() if any(ch in pattern for ch in "*?[") else f"*{pattern.lower()}*"
        return replace(
            self,
            channels=[c for c in self.channels if fnmatch.fnmatchcase(c.name.lower(), glob)],
            can_ids=[i for i in self.can_ids if fnmatch.fnmatchcase(f"{i.label} {i.message or ''}".lower(), glob)],
        )

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: ``path``, ``kind``, ``truncated``, ``channels`` (with ``shape`` for MATLAB and HDF5
        variables) or ``can_ids`` (and ``frames`` for CAN logs)."""
        out: dict[str, Any] = {"path": self.path, "kind": self.kind, "truncated": self.truncated}
        if self.kind == "can":
            out["frames"] = self.frames
            out["can_ids"] = [{**asdict(i), "id": i.label} for i in self.can_ids]
        else:
            # a shape only where the format has arrays (MATLAB, HDF5): the other formats' keys stay as they were
            out["channels"] = [_channel_dict(c) for c in self.channels]
        return out


def _channel_dict(channel: ChannelInfo) -> dict[str, Any]:
    """A channel as JSON; ``shape`` only where the format has arrays (MATLAB, HDF5)."""
    return {k: v for k, v in asdict(channel).items() if k != "shape" or v is not None}


def inspect_file(
    path: str | os.PathLike[str], dbc: str | os.PathLike[str] | None = None, **csv_options: str | None
) -> FileSummary:
    """List what the file at ``path`` holds (its format chosen as :func:`~online_backlash.replay.open_log` does).

    ``dbc`` names the CAN IDs of a CAN log; ``csv_options`` (``delimiter``, ``decimal``, ``comment``, ``encoding``)
    override what is sniffed of a CSV (:func:`~online_backlash.replay.csv.sniff_dialect`). Raises LogFormatError for a
    file that cannot be read (a CSV row with another number of fields than its header, named by its line) or a
    format with nothing to list (a raw serial capture).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise LogFormatError(path, None, "no such file" if not os.path.exists(path) else "not a file: inspect one file")
    suffix = file_suffix(path)
    if suffix in CSV_SUFFIXES:
        return FileSummary(path, "csv", _csv_columns(path, **csv_options))
    if is_measurement_log(path):
        if suffix in (".mf4", ".mdf"):
            from .replay.mdf import describe as mdf_channels

            return FileSummary(path, "mdf", mdf_channels(path))
        if suffix == ".tdms":
            from .replay.tdms import describe as tdms_channels

            channels, cut = tdms_channels(path)
            return FileSummary(path, "tdms", channels, truncated=cut)
        if suffix in (".mat", ".h5", ".hdf5"):
            return _variables(path)
        from .replay.parquet import ARROW_SUFFIXES
        from .replay.parquet import describe as table_columns

        return FileSummary(path, "arrow" if suffix in ARROW_SUFFIXES else "parquet", table_columns(path))
    from .replay.canlog import CAN_LOG_SUFFIXES

    if suffix in CAN_LOG_SUFFIXES:
        return _can_ids(path, dbc)
    known = sorted({*CSV_SUFFIXES, *MEASUREMENT_READERS, *CAN_LOG_SUFFIXES})
    raise LogFormatError(path, None, f"inspect reads {', '.join(known)} files, not {suffix or 'files without a suffix'!r}")


def _variables(path: str) -> FileSummary:
    """A MATLAB or HDF5 file's variables (struct fields, group/datasets) with shape, type, length, unit."""
    from .replay.hdf5 import describe as hdf5_variables
    from .replay.matv5 import describe as mat_variables
    from .replay.matv5 import is_mat_v73

    if file_suffix(path) == ".mat" and not is_mat_v73(path):
        return FileSummary(path, "mat", mat_variables(path))
    kind, variables = hdf5_variables(path)
    return FileSummary(path, kind, variables)


def _csv_columns(
    path: str, delimiter: str | None = None, decimal: str | None = None, comment: str | None = None,
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


def _can_ids(path: str, dbc: str | os.PathLike[str] | None) -> FileSummary:
    """Frames per CAN ID of a python-can log, with the DBC's message names (a truncated BLF: up to the cut)."""
    from .replay.canlog import blf_cut, open_can_log

    names = _dbc_names(dbc) if dbc is not None else {}
    counts: Counter[tuple[int, bool]] = Counter()
    first: dict[tuple[int, bool], float] = {}
    last: dict[tuple[int, bool], float] = {}
    index = 0
    try:
        with open_can_log(Path(path)) as reader:
            for index, message in enumerate(reader):  # noqa: B007 (index names the failing frame)
                if message.is_error_frame:
                    continue
                key = (message.arbitration_id, message.is_extended_id)
                counts[key] += 1
                first.setdefault(key, message.timestamp)
                last[key] = message.timestamp
        cut = blf_cut(Path(path), reader)
    except LogFormatError:
        raise
    except Exception as exc:  # every python-can reader fails its own way on a damaged file
        raise LogFormatError(path, index, f"cannot read the CAN log ({type(exc).__name__}: {exc})") from exc
    ids = []
    for (can_id, extended), n in sorted(counts.items()):
        span = last[(can_id, extended)] - first[(can_id, extended)]
        rate = float(f"{(n - 1) / span:.6g}") if n > 1 and span > 0 else None
        ids.append(CanIdInfo(can_id, extended, n, rate, names.get((can_id, extended))))
    return FileSummary(path, "can", can_ids=ids, frames=sum(counts.values()), truncated=cut)


def _dbc_names(dbc: str | os.PathLike[str]) -> dict[tuple[int, bool], str]:
    import cantools

    try:
        database = cantools.database.load_file(os.fspath(dbc))
    except Exception as exc:  # cantools raises its own parse errors and OSErrors
        raise LogFormatError(dbc, None, f"cannot load the DBC ({type(exc).__name__}: {exc})") from exc
    return {(m.frame_id, m.is_extended_frame): m.name for m in getattr(database, "messages", [])}

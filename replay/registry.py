"""Which format reads which recorded log: :data:`FORMATS`, the only table of them, and :func:`open_log`.

Each format is one :class:`~online_backlash.replay.formats.LogFormat` (its suffixes, how it recognises its
files where a suffix is shared, its reader, what ``inspect`` prints, its typed options), exported by its reader's
module. A new format is one module with its ``LogFormat`` plus one line :func:`register_format` (or one entry in
:data:`FORMATS`).
Readers of heavy formats are imported on use (cantools loads only for CAN logs). The readers import nothing
from here or from the package ``__init__``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleChunk, SampleSource, read_all

from .csv import CSV
from .formats import CAN, MF4, LogFormat
from .hdf5 import HDF5
from .matv5 import MAT
from .mdf import MDF
from .parquet import ARROW, PARQUET
from .paths import file_suffix
from .serialcapture import SERIAL
from .tdms import TDMS

#: Every format, in the order a shared suffix is tried: a format that ``recognises`` its files by content comes
#: before the one that takes the rest (an ``.mf4`` of signals is MDF, any other a CAN log).
FORMATS: list[LogFormat] = [CSV, MDF, TDMS, PARQUET, ARROW, MAT, HDF5, CAN, SERIAL]

#: python-can's log suffixes but ``.csv`` (ours) and ``.mf4`` (by content); a test holds it equal to python-can's table.
CAN_LOG_SUFFIXES = tuple(s for s in CAN.suffixes if s != MF4)


def register_format(log_format: LogFormat) -> None:
    """Add a format to :data:`FORMATS` (before the formats without a content test that share a suffix with it)."""
    takers = [i for i, f in enumerate(FORMATS) if f.recognises is None and set(f.suffixes) & set(log_format.suffixes)]
    FORMATS.insert(takers[0] if takers else len(FORMATS), log_format)
    LOG_READERS.clear()
    LOG_READERS.update(_readers())


def formats_for(suffix: str) -> tuple[LogFormat, ...]:
    """The formats that read files with ``suffix``, in the order they are tried."""
    return tuple(f for f in FORMATS if suffix in f.suffixes)


def suffixes(formats: list[LogFormat] | None = None) -> list[str]:
    """Every suffix of ``formats`` (default: all), sorted."""
    return sorted({s for f in (FORMATS if formats is None else formats) for s in f.suffixes})


def find_format(path: str | os.PathLike[str]) -> LogFormat | None:
    """The format of the log at ``path`` by its suffix (and content where a suffix is shared); None if unknown."""
    candidates = formats_for(log_suffix(path))
    return next((f for f in candidates if f.recognises is None or f.recognises(path)), None)


def format_of(path: str | os.PathLike[str]) -> LogFormat:
    """:func:`find_format`, or LogFormatError naming the file (no such file, or an unknown suffix)."""
    found = find_format(path)
    if found is None:
        suffix = log_suffix(path)
        if not suffix and not os.path.exists(path):  # e.g. a folder name misspelt: say so, not "unknown format ''"
            raise LogFormatError(path, None, "no such file or folder")
        raise LogFormatError(path, None, f"unknown log format {suffix!r}; known: {suffixes()}")
    return found


def _open_by_content(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """The reader of a suffix several formats share (:func:`open_log`)."""
    return open_log(path, **options)


def _readers() -> dict[str, Callable[..., SampleSource]]:
    """suffix -> reader, derived from :data:`FORMATS` (a shared suffix opens by content)."""
    return {s: f.open if len(formats_for(s)) == 1 else _open_by_content for f in FORMATS for s in f.suffixes}


#: suffix -> reader, a view of :data:`FORMATS` (each reader takes ``(path, **options)`` and returns a SampleSource).
LOG_READERS: dict[str, Callable[..., SampleSource]] = _readers()


def log_suffix(path: str | os.PathLike[str]) -> str:
    """The suffix that selects the reader: ``.csv`` for ``run.csv`` and ``run.csv.gz``.

    For a directory, the suffix of its files, which must all be read by one reader (CAN logs
    or ``.serial`` captures; names starting with ``.`` are ignored); otherwise LogFormatError.
    """
    if os.path.isdir(path):
        return _directory_suffix(path)
    return file_suffix(path)


def _directory_suffix(directory: str | os.PathLike[str]) -> str:
    names = sorted(e.name for e in os.scandir(directory) if not e.name.startswith("."))
    if not names:
        raise LogFormatError(directory, None, "empty directory: no log files")
    found = {log_suffix(os.path.join(directory, n)) for n in names}
    readers = {formats_for(s) for s in found}
    if len(readers) != 1 or () in readers:
        raise LogFormatError(
            directory,
            None,
            f"a log directory must hold files of one format, found suffixes {sorted(found)} in {names[:5]}...",
        )
    if not any(f.directories for f in readers.pop()):
        raise LogFormatError(directory, None, f"a directory of {sorted(found)} logs is not supported; give one file")
    return min(found)


def open_log(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """Open a recorded log as a :class:`~online_backlash.stream.SampleSource`, choosing the reader by suffix.

    ``path`` may also be a directory of CAN logs or of serial captures (all one format, as
    written by ``listen --raw-log DIR``): they are read in name order as one stream.
    """
    return format_of(path).open(path, **options)


def read_log_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole log of any registered format (or a directory, see :func:`open_log`) into one :class:`SampleChunk`
    (for batch fits)."""
    return read_all(open_log(path, **options), path)

"""Recorded logs replayed as the same sample stream as the live adapters.

:func:`open_log` picks a reader by the file's suffix from :data:`LOG_READERS` (a ``.gz``
suffix is looked through); a new format is one class plus one entry here.
"""

from __future__ import annotations

import os
from typing import Any, Callable

import numpy as np
from can.io.player import MESSAGE_READERS as _CAN_MESSAGE_READERS

from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleChunk

from .csv import CsvLog, read_csv_arrays

#: suffix -> reader class; each reader takes ``(path, **options)`` and is a Source.
LOG_READERS: dict[str, Callable[..., Any]] = {
    ".csv": CsvLog,
}


def _can_log(path: str | os.PathLike[str], **options: Any):
    """A CAN log in a python-can format, decoded with a DBC (:class:`~online_backlash.replay.canlog.CanLog`)."""
    from .canlog import CanLog  # imported on use: cantools loads only for CAN logs

    return CanLog(path, **options)


def _serial_capture(path: str | os.PathLike[str], **options: Any):
    """A raw serial capture (:class:`~online_backlash.replay.serialcapture.SerialCapture`)."""
    from .serialcapture import SerialCapture

    return SerialCapture(path, **options)


# every format python-can's LogReader reads (.asc .blf .log .trc .db .mf4), except .csv which is ours
LOG_READERS.update({suffix: _can_log for suffix in _CAN_MESSAGE_READERS if suffix not in LOG_READERS})
LOG_READERS[".serial"] = _serial_capture


#: Readers that also take a directory of their files (read in name order, e.g. a ``--raw-log`` directory).
DIRECTORY_READERS = (_can_log, _serial_capture)


def log_suffix(path: str | os.PathLike[str]) -> str:
    """The suffix that selects the reader: ``.csv`` for ``run.csv`` and ``run.csv.gz``.

    For a directory, the suffix of its files, which must all be read by one reader (CAN logs
    or ``.serial`` captures; names starting with ``.`` are ignored); otherwise LogFormatError.
    """
    if os.path.isdir(path):
        return _directory_suffix(path)
    name = os.fspath(path).lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return os.path.splitext(name)[1]


def _directory_suffix(directory: str | os.PathLike[str]) -> str:
    names = sorted(e.name for e in os.scandir(directory) if not e.name.startswith("."))
    if not names:
        raise LogFormatError(directory, None, "empty directory: no log files")
    suffixes = {log_suffix(os.path.join(directory, n)) for n in names}
    readers = {LOG_READERS.get(s) for s in suffixes}
    if len(readers) != 1 or None in readers:
        raise LogFormatError(directory, None, f"a log directory must hold files of one format, found suffixes {sorted(suffixes)} in {names[:5]}...")
    if readers.pop() not in DIRECTORY_READERS:
        raise LogFormatError(directory, None, f"a directory of {sorted(suffixes)} logs is not supported; give one file")
    return min(suffixes)


def open_log(path: str | os.PathLike[str], **options: Any):
    """Open a recorded log as a Source, choosing the reader by suffix.

    ``path`` may also be a directory of CAN logs or of serial captures (all one format, as
    written by ``listen --raw-log DIR``): they are read in name order as one stream.
    """
    suffix = log_suffix(path)
    try:
        reader = LOG_READERS[suffix]
    except KeyError:
        raise LogFormatError(path, None, f"unknown log format {suffix!r}; known: {sorted(LOG_READERS)}") from None
    return reader(path, **options)


def read_log_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole log of any registered format (or a directory, see :func:`open_log`) into one :class:`SampleChunk` (for batch fits)."""
    with open_log(path, **options) as log:
        chunks = [c for c in log.iter_chunks() if len(c)]
    if not chunks:
        raise LogFormatError(path, None, "no samples")
    return SampleChunk(*(np.concatenate([getattr(c, f) for c in chunks]) for f in ("time_s", "motor_deg", "load_deg", "torque_Nm", "after_gap")))


__all__ = ["CsvLog", "DIRECTORY_READERS", "LOG_READERS", "log_suffix", "open_log", "read_csv_arrays", "read_log_arrays"]

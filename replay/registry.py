"""Which reader opens which recorded log: :data:`LOG_READERS` by suffix, and :func:`open_log`.

A new format is one :class:`~online_backlash.stream.SampleSource` class plus one entry in
:data:`LOG_READERS`. Readers of heavy formats are imported on use (cantools loads only for CAN
logs). The readers import nothing from here or from the package ``__init__``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleChunk, SampleSource, read_all

from .csv import CSV_SUFFIXES, CsvLog
from .measurement import MEASUREMENT_READERS, MF4, open_mdf_or_can
from .paths import file_suffix

#: suffix -> reader; each reader takes ``(path, **options)`` and returns a SampleSource.
LOG_READERS: dict[str, Callable[..., SampleSource]] = {suffix: CsvLog for suffix in CSV_SUFFIXES}


def _can_log(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A CAN log in a python-can format, decoded with a DBC (:class:`~online_backlash.replay.canlog.CanLog`)
    or, given ``eds``, with a CANopen drive's object dictionary (:class:`~online_backlash.replay.canopenlog.CanopenLog`)."""
    if options.get("eds") is not None:
        from .canopenlog import CanopenLog  # imported on use: canopen loads only for CANopen logs

        return CanopenLog(path, **options)
    from .canlog import CanLog  # imported on use: cantools loads only for CAN logs

    return CanLog(path, **options)


def _serial_capture(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A raw serial capture (:class:`~online_backlash.replay.serialcapture.SerialCapture`)."""
    from .serialcapture import SerialCapture

    return SerialCapture(path, **options)


#: Every format python-can's LogReader reads (``can.io.player.MESSAGE_READERS``) but ``.csv``, which is ours,
#: and ``.mf4`` (by content, below); named here so python-can (and the asammdf and pandas it loads,
#: 55 MB) is imported only when a CAN log is read. A test holds it equal to python-can's table.
CAN_LOG_SUFFIXES = (".asc", ".blf", ".db", ".log", ".trc")
LOG_READERS.update({suffix: _can_log for suffix in CAN_LOG_SUFFIXES})
LOG_READERS[".serial"] = _serial_capture


def _mf4(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """An ``.mf4``: CAN bus logging (a CAN log) or measured signals (an MDF measurement file), by content."""
    return open_mdf_or_can(path, _can_log, **options)


LOG_READERS.update(MEASUREMENT_READERS)
LOG_READERS[MF4] = _mf4


#: Readers that also take a directory of their files (read in name order, e.g. a ``--raw-log`` directory).
DIRECTORY_READERS: tuple[Callable[..., SampleSource], ...] = (_can_log, _serial_capture, _mf4)


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
    suffixes = {log_suffix(os.path.join(directory, n)) for n in names}
    readers = {LOG_READERS.get(s) for s in suffixes}
    if len(readers) != 1 or None in readers:
        raise LogFormatError(directory, None, f"a log directory must hold files of one format, found suffixes {sorted(suffixes)} in {names[:5]}...")
    if readers.pop() not in DIRECTORY_READERS:
        raise LogFormatError(directory, None, f"a directory of {sorted(suffixes)} logs is not supported; give one file")
    return min(suffixes)


def open_log(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """Open a recorded log as a :class:`~online_backlash.stream.SampleSource`, choosing the reader by suffix.

    ``path`` may also be a directory of CAN logs or of serial captures (all one format, as
    written by ``listen --raw-log DIR``): they are read in name order as one stream.
    """
    suffix = log_suffix(path)
    try:
        reader = LOG_READERS[suffix]
    except KeyError:
        if not suffix and not os.path.exists(path):  # e.g. a folder name misspelt: say so, not "unknown format ''"
            raise LogFormatError(path, None, "no such file or folder") from None
        raise LogFormatError(path, None, f"unknown log format {suffix!r}; known: {sorted(LOG_READERS)}") from None
    return reader(path, **options)


def read_log_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole log of any registered format (or a directory, see :func:`open_log`) into one :class:`SampleChunk` (for batch fits)."""
    return read_all(open_log(path, **options), path)

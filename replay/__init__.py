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


def log_suffix(path: str | os.PathLike[str]) -> str:
    """The suffix that selects the reader: ``.csv`` for ``run.csv`` and ``run.csv.gz``."""
    name = os.fspath(path).lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return os.path.splitext(name)[1]


def open_log(path: str | os.PathLike[str], **options: Any):
    """Open a recorded log as a Source, choosing the reader by suffix."""
    suffix = log_suffix(path)
    try:
        reader = LOG_READERS[suffix]
    except KeyError:
        raise LogFormatError(path, None, f"unknown log format {suffix!r}; known: {sorted(LOG_READERS)}") from None
    return reader(path, **options)


def read_log_arrays(path: str | os.PathLike[str], **options: Any) -> SampleChunk:
    """Read a whole log of any registered format into one :class:`SampleChunk` (for batch fits)."""
    with open_log(path, **options) as log:
        chunks = [c for c in log.iter_chunks() if len(c)]
    if not chunks:
        raise LogFormatError(path, None, "no samples")
    return SampleChunk(*(np.concatenate([getattr(c, f) for c in chunks]) for f in ("time_s", "motor_deg", "load_deg", "torque_Nm", "after_gap")))


__all__ = ["CsvLog", "LOG_READERS", "log_suffix", "open_log", "read_csv_arrays", "read_log_arrays"]

"""Recorded logs replayed as the same sample stream as the live adapters.

:func:`open_log` picks a format by the file's suffix (a ``.gz`` suffix is looked through), and by its
content where formats share a suffix, from :data:`~online_backlash.replay.registry.FORMATS`; a new format
is one module with its :class:`~online_backlash.replay.formats.LogFormat` plus one registry line.

::

    registry.py       FORMATS (the only table), register_format, format_of, open_log, read_log_arrays, log_suffix
    formats.py        LogFormat and the formats: suffixes, content test, reader, inspect's describe, options
    options.py        the readers' typed options (Columns, Units, Counts, Timing, CsvDialect, CanDecoding, ...)
    summary.py        FileSummary, CanIdInfo: what inspect lists
    csv.py            CsvLog: CSV rows (pandas' C parser in blocks)
    canlog.py         CanLog: python-can's log formats decoded with a DBC (blocks, compiled pairing)
    canopenlog.py     CanopenLog: the same logs of CANopen drives, decoded with their EDS/DCF (SYNC groups)
    serialcapture.py  SerialCapture: raw serial captures through the live parser
    matv5.py          MatV5Log: MATLAB v4-v7 .mat files (scipy.io)
    hdf5.py           Hdf5Log: HDF5 files and MATLAB v7.3 .mat files (h5py), read in slices
    variables.py      what those two share: the tree of variables, names resolved to roles, blocks along samples
    paths.py          a file's suffix
"""

from __future__ import annotations

from .csv import CsvLog, read_csv_arrays
from .formats import LogFormat
from .registry import FORMATS, LOG_READERS, format_of, log_suffix, open_log, read_log_arrays, register_format

__all__ = [
    "FORMATS",
    "LOG_READERS",
    "CsvLog",
    "LogFormat",
    "format_of",
    "log_suffix",
    "open_log",
    "read_csv_arrays",
    "read_log_arrays",
    "register_format",
]

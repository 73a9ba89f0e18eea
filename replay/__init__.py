"""Recorded logs replayed as the same sample stream as the live adapters.

:func:`open_log` picks a reader by the file's suffix from :data:`LOG_READERS` (a ``.gz``
suffix is looked through); a new format is one :class:`~online_backlash.stream.SampleSource`
class plus one entry in :mod:`~online_backlash.replay.registry`.

::

    registry.py       LOG_READERS, open_log, read_log_arrays, log_suffix
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
from .registry import DIRECTORY_READERS, LOG_READERS, log_suffix, open_log, read_log_arrays

__all__ = ["DIRECTORY_READERS", "LOG_READERS", "CsvLog", "log_suffix", "open_log", "read_csv_arrays", "read_log_arrays"]

"""Measurement files (MDF, TDMS, Parquet/Arrow, MATLAB, HDF5) in the reader registry, ``.mf4`` and ``.mat`` by content.

An ``.mf4``/``.mdf`` file is either bus logging (CAN frames, which python-can reads: a CAN log
decoded with a DBC) or measured signals (a measurement file): :func:`is_measurement_log` decides
from the file's content, so the CLI knows which options to pass and :func:`open_mdf_or_can`
opens the right reader. A ``.mat`` file is MATLAB v4-v7 (scipy) or v7.3 (HDF5, h5py): :func:`_mat`
decides from its header. Readers are imported on use (asammdf, npTDMS, pyarrow, h5py are heavy).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

from online_backlash.stream import SampleSource

from .paths import file_suffix


def _mdf(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .mdf import MdfLog

    return MdfLog(path, **options)


def _tdms(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .tdms import TdmsLog

    return TdmsLog(path, **options)


def _parquet(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .parquet import ParquetLog

    return ParquetLog(path, **options)


def _hdf5(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .hdf5 import Hdf5Log

    return Hdf5Log(path, **options)


def _mat(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A MATLAB file: v7.3 (HDF5 inside) or v4-v7, by its header."""
    from .matv5 import MatV5Log, is_mat_v73

    return _hdf5(path, **options) if os.path.isfile(path) and is_mat_v73(path) else MatV5Log(path, **options)


#: suffix -> reader of the measurement-file formats (``.mf4`` is decided by content: :func:`open_mdf_or_can`).
MEASUREMENT_READERS: dict[str, Callable[..., SampleSource]] = {
    ".mdf": _mdf,
    ".tdms": _tdms,
    ".parquet": _parquet,
    ".pq": _parquet,
    ".arrow": _parquet,
    ".feather": _parquet,
    ".ipc": _parquet,
    ".mat": _mat,
    ".h5": _hdf5,
    ".hdf5": _hdf5,
}
#: The suffix of both CAN bus logging (python-can's MF4 format) and measured signals.
MF4 = ".mf4"


def is_measurement_log(path: str | os.PathLike[str]) -> bool:
    """True for a measurement file: TDMS, Parquet/Arrow, or an MDF file of signals (not of CAN frames)."""
    suffix = file_suffix(path)
    if suffix == MF4:
        from .mdf import is_bus_logging

        return os.path.isfile(path) and not is_bus_logging(path)
    return suffix in MEASUREMENT_READERS


def open_mdf_or_can(path: str | os.PathLike[str], can_reader: Callable[..., SampleSource], **options: Any) -> SampleSource:
    """An MDF file as a measurement file, or with ``can_reader`` when it is CAN bus logging (or a directory of logs)."""
    return _mdf(path, **options) if is_measurement_log(path) else can_reader(path, **options)

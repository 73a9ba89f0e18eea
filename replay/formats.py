"""The recorded-log formats: one :class:`LogFormat` each, declared once (issue 29).

A format says which suffixes it reads, how it tells its files from another format's where a suffix
is shared (an ``.mf4`` of measured signals or of CAN bus logging), how a file is opened as a
:class:`~online_backlash.stream.SampleSource` (``open``), what ``inspect`` prints of it (``describe``) and
which typed options (:mod:`~online_backlash.replay.options`) its reader takes. The table that chooses among
them is :data:`~online_backlash.replay.registry.FORMATS`. The readers of heavy formats (python-can and
cantools, asammdf, npTDMS, pyarrow, scipy, h5py) are imported on use, so each format's ``open`` and
``describe`` below import their module when called, as python-can's ``LogReader`` looks its reader up by suffix.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from online_backlash.codecs.options import FrameRules, gather_options
from online_backlash.errors import InvalidParameterError
from online_backlash.stream import SampleSource

from .csv import CSV_SUFFIXES, CsvLog
from .options import (
    BadRows,
    CanDecoding,
    Columns,
    Counts,
    CsvDialect,
    Pace,
    ReaderOption,
    SerialFraming,
    Timing,
    Units,
    WholeCounts,
)
from .paths import file_suffix
from .summary import FileSummary


@dataclass(frozen=True)
class LogFormat:
    """One recorded-log format.

    Attributes
    ----------
    kind : str
        Its name, as ``inspect --json`` prints it (``"csv"``, ``"mdf"``, ``"can"``, ...).
    suffixes : tuple of str
        The suffixes it reads (``.gz`` is looked through for text formats,
        :func:`~online_backlash.replay.paths.file_suffix`).
    open : callable
        ``open(path, **kwargs) -> SampleSource``: the reader, with the keyword arguments of its options.
    options : tuple of ReaderOption types
        The typed options its reader takes (:meth:`reader_kwargs` turns them into the keyword arguments).
    describe : callable, optional
        ``describe(path, **inspect_options) -> FileSummary`` for ``inspect`` (None: nothing to list, e.g. a raw
        serial capture); ``inspect_options`` are ``dbc`` and the CSV dialect's overrides, each taken where it applies.
    recognises : callable, optional
        ``recognises(path) -> bool`` where a suffix is shared with a later format: the file's content decides
        (None: every file of its suffixes is its own).
    directories : bool
        Whether a directory of its files is read as one stream (``listen --raw-log`` folders).
    title : str
        What a user calls its files, and what reading one needs (the CLI's help of a log argument,
        :meth:`help_text`).
    """

    kind: str
    suffixes: tuple[str, ...]
    open: Callable[..., SampleSource]
    options: tuple[type[ReaderOption], ...] = ()
    describe: Callable[..., FileSummary] | None = None
    recognises: Callable[[str | os.PathLike[str]], bool] | None = None
    directories: bool = False
    title: str = ""

    def help_text(self) -> str:
        """Its suffixes and title, as the CLI's help lists it: ``.tdms (TDMS, channels by --columns)``."""
        return " ".join(self.suffixes) + (f" ({self.title})" if self.title else "")

    def reader_kwargs(self, options: Iterable[ReaderOption]) -> dict[str, Any]:
        """The reader's keyword arguments from ``options``, each of a type this format takes (else
        InvalidParameterError)."""
        kwargs: dict[str, Any] = {}
        for option in options:
            if type(option) not in self.options:
                raise InvalidParameterError(f"a {self.kind} log takes no {type(option).__name__} options")
            kwargs.update(option.kwargs())
        return kwargs


def _describe_csv(path: str, dbc: Any = None, **dialect: str | None) -> FileSummary:
    from .csv import describe

    return describe(path, **dialect)


def _can_log(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A CAN log in a python-can format, decoded with a DBC (:class:`~online_backlash.replay.canlog.CanLog`)
    or, given ``eds``, with a CANopen drive's object dictionary
    (:class:`~online_backlash.replay.canopenlog.CanopenLog`);
    ``options`` are the fields of its options (:func:`~online_backlash.codecs.options.gather_options`)."""
    given = gather_options(options, decoding=CanDecoding, counts=Counts, frames=FrameRules)
    if given["decoding"].canopen is not None:
        from .canopenlog import CanopenLog  # imported on use: canopen loads only for CANopen logs

        return CanopenLog(path, **given)
    from .canlog import CanLog  # imported on use: cantools loads only for CAN logs

    return CanLog(path, **given)


def _describe_can(path: str, dbc: str | os.PathLike[str] | None = None, **_: Any) -> FileSummary:
    from .canlog import describe

    return describe(path, dbc)


def _open_serial(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A raw serial capture (:class:`~online_backlash.replay.serialcapture.SerialCapture`); ``options`` are the fields
    of its options (:func:`~online_backlash.codecs.options.gather_options`)."""
    from .serialcapture import SerialCapture

    return SerialCapture(path, **gather_options(options, counts=Counts, frames=FrameRules))


def _open_mdf(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .mdf import MdfLog

    return MdfLog(path, **options)


def _describe_mdf(path: str, **_: Any) -> FileSummary:
    from .mdf import describe

    return FileSummary(path, "mdf", describe(path))


def _holds_signals(path: str | os.PathLike[str]) -> bool:
    """An ``.mdf`` is always measured signals; an ``.mf4`` only when it is a file not of CAN bus logging."""
    if file_suffix(path) != MF4:
        return True
    from .mdf import is_bus_logging

    return os.path.isfile(path) and not is_bus_logging(path)


def _open_tdms(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .tdms import TdmsLog

    return TdmsLog(path, **options)


def _describe_tdms(path: str, **_: Any) -> FileSummary:
    from .tdms import describe

    channels, cut = describe(path)
    return FileSummary(path, "tdms", channels, truncated=cut)


def _open_table(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .parquet import ParquetLog

    return ParquetLog(path, **options)


def _table_describer(kind: str) -> Callable[..., FileSummary]:
    def describe_table(path: str, **_: Any) -> FileSummary:
        """The columns of a Parquet or Arrow file."""
        from .parquet import describe

        return FileSummary(path, kind, describe(path))

    return describe_table


def _open_hdf5(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    from .hdf5 import Hdf5Log

    return Hdf5Log(path, **options)


def _describe_hdf5(path: str, **_: Any) -> FileSummary:
    """An HDF5 file's (or a MATLAB v7.3 file's) variables: ``mat-v7.3`` or ``hdf5``."""
    from .hdf5 import describe

    kind, variables = describe(path)
    return FileSummary(path, kind, variables)


def _open_mat(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A MATLAB file: v7.3 (HDF5 inside) or v4-v7, by its header."""
    from .matv5 import MatV5Log, is_mat_v73

    return _open_hdf5(path, **options) if os.path.isfile(path) and is_mat_v73(path) else MatV5Log(path, **options)


def _describe_mat(path: str, **_: Any) -> FileSummary:
    from .matv5 import describe, is_mat_v73

    return _describe_hdf5(path) if is_mat_v73(path) else FileSummary(path, "mat", describe(path))


#: The suffix of both CAN bus logging (python-can's MF4 format) and measured signals.
MF4 = ".mf4"
#: What a file of columns or channels takes: the roles' names, the angles' units, bad rows skipped or not.
_TABULAR = (Columns, Units, Counts, BadRows)

_CHANNELS = "channels by --columns"
CSV = LogFormat(
    "csv",
    CSV_SUFFIXES,
    CsvLog,
    (*_TABULAR, Timing, CsvDialect),
    _describe_csv,
    title="CSV or delimited text, also .gz; a torque column is used when mapped",
)
MDF = LogFormat(
    "mdf", (MF4, ".mdf"), _open_mdf, _TABULAR, _describe_mdf, recognises=_holds_signals, title=f"MDF, {_CHANNELS}"
)
TDMS = LogFormat("tdms", (".tdms",), _open_tdms, _TABULAR, _describe_tdms, title=f"TDMS, {_CHANNELS}")
PARQUET = LogFormat(
    "parquet", (".parquet", ".pq"), _open_table, _TABULAR, _table_describer("parquet"), title=f"Parquet, {_CHANNELS}"
)
ARROW = LogFormat(
    "arrow",
    (".arrow", ".feather", ".ipc"),
    _open_table,
    _TABULAR,
    _table_describer("arrow"),
    title=f"Arrow IPC, {_CHANNELS}",
)
MAT = LogFormat("mat", (".mat",), _open_mat, _TABULAR, _describe_mat, title=f"MATLAB v4-v7.3, {_CHANNELS}")
HDF5 = LogFormat("hdf5", (".h5", ".hdf5"), _open_hdf5, _TABULAR, _describe_hdf5, title=f"HDF5, {_CHANNELS}")
#: Every format python-can's LogReader reads (``can.io.player.MESSAGE_READERS``) but ``.csv``, which is ours; named
#: here so python-can (and the asammdf and pandas it loads, 55 MB) is imported only when a CAN log is read. A test
#: holds it equal to python-can's table. Its ``.mf4`` files are those :data:`MDF` does not recognise.
CAN = LogFormat(
    "can",
    (".asc", ".blf", ".db", ".log", ".trc", MF4),
    _can_log,
    (CanDecoding, WholeCounts, BadRows, Pace, Timing),
    _describe_can,
    directories=True,
    title="a CAN log, also .gz, with --dbc or --eds",
)
SERIAL = LogFormat(
    "serial",
    (".serial",),
    _open_serial,
    (SerialFraming, Counts, BadRows, Pace, Timing),
    directories=True,
    title="a serial capture, with --serial-format",
)

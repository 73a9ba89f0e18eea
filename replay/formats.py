"""What a recorded-log format is: :class:`LogFormat`, declared once per format next to its reader (issue 29).

A format says which suffixes it reads, how it tells its files from another format's where a suffix
is shared (an ``.mf4`` of measured signals or of CAN bus logging), how a file is opened as a
:class:`~online_backlash.stream.SampleSource` (``open``), what ``inspect`` prints of it (``describe``) and
which typed options (:mod:`~online_backlash.replay.options`) its reader takes. The table that chooses among
them is :data:`~online_backlash.replay.registry.FORMATS`. Each reader module exports its format (``csv.CSV``,
``mdf.MDF``, ``tdms.TDMS``, ``parquet.PARQUET`` and ``ARROW``, ``matv5.MAT``, ``hdf5.HDF5``,
``serialcapture.SERIAL``) and imports its heavy library (asammdf, npTDMS, pyarrow, scipy, h5py) on use. The CAN
format is declared here: its readers' modules import python-can and cantools (55 MB with the asammdf and pandas
they load), which must not load when another format is read.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from online_backlash.codecs.options import FrameRules, gather_options
from online_backlash.errors import InvalidParameterError
from online_backlash.stream import SampleSource

from .options import (
    BadRows,
    CanDecoding,
    Columns,
    Counts,
    Pace,
    ReaderOption,
    Timing,
    Units,
    WholeCounts,
)
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


#: The suffix of both CAN bus logging (python-can's MF4 format) and measured signals.
MF4 = ".mf4"
#: What a file of columns or channels takes: the roles' names, the angles' units, bad rows skipped or not.
TABULAR = (Columns, Units, Counts, BadRows)

#: The title of a format of channels or columns (:attr:`LogFormat.title`).
CHANNELS = "channels by --columns"

#: Every format python-can's LogReader reads (``can.io.player.MESSAGE_READERS``) but ``.csv``, which is ours; named
#: here so python-can (and the asammdf and pandas it loads, 55 MB) is imported only when a CAN log is read. A test
#: holds it equal to python-can's table. Its ``.mf4`` files are those
#: :data:`~online_backlash.replay.mdf.MDF` does not recognise.
CAN = LogFormat(
    "can",
    (".asc", ".blf", ".db", ".log", ".trc", MF4),
    _can_log,
    (CanDecoding, WholeCounts, BadRows, Pace, Timing),
    _describe_can,
    directories=True,
    title="a CAN log, also .gz, with --dbc or --eds",
)

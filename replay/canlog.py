"""Recorded CAN logs (every format python-can's ``LogReader`` reads) decoded with a DBC.

The frames go through the same :class:`~online_backlash.drivers.pairing.FramePipeline` as the
live :class:`~online_backlash.drivers.can.CanSource`, so a raw log recorded live replays to the
same samples. Reading runs flat out; ``realtime=True`` paces to the recorded timestamps with
python-can's :class:`can.MessageSync`.

A reader that fails (truncated or malformed file) raises :class:`LogFormatError` naming the file
and the 0-based index of the frame it could not read; with ``skip_bad=True`` the failure is
counted as one corrupt frame and that file ends there (python-can's readers cannot resume).
"""

from __future__ import annotations

import gzip
import os
from pathlib import Path
from typing import Iterator

import can
from cantools.database.can import Database

from online_backlash.drivers.dbc import DbcDecoder
from online_backlash.drivers.pairing import CanCounters, FramePipeline
from online_backlash.drivers.rawlog import raw_log_files
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.replay import log_suffix
from online_backlash.stream import Sample, SampleChunk, chunked

#: Suffixes python-can reads (``.csv`` is ours: see :mod:`online_backlash.replay.csv`).
CAN_LOG_SUFFIXES = tuple(s for s in can.io.player.MESSAGE_READERS if s != ".csv")


class CanLog:
    """A recorded CAN log (or a directory of them, in name order) as a sample Source.

    Parameters
    ----------
    path : path
        A ``.asc``, ``.blf``, ``.log`` (candump), ``.trc``, ``.db`` or ``.mf4`` file (``.gz`` too),
        or a directory whose CAN log files are read in name order (a ``--raw-log`` directory).
    dbc, motor_signal, load_signal, motor_cpr, load_cpr, counter_signal, checksum_signal
        See :class:`~online_backlash.drivers.dbc.DbcDecoder`.
    period_s, max_skew_s, strict
        See :class:`~online_backlash.drivers.pairing.FramePipeline`.
    skip_bad : bool
        Count a reader failure as corrupt and end that file instead of raising.
    realtime : bool
        Pace to the recorded timestamps.

    Attributes
    ----------
    counters : CanCounters
        Reconcile at the end of iteration (see :mod:`~online_backlash.drivers.pairing`).
    pipeline : FramePipeline
        The pairing skew of the last iteration.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        dbc: str | os.PathLike[str] | Database | None = None,
        motor_signal: str | None = None,
        load_signal: str | None = None,
        *,
        motor_cpr: int | None = None,
        load_cpr: int | None = None,
        counter_signal: str | None = "Counter",
        checksum_signal: str | None = "Checksum",
        period_s: float | None = None,
        max_skew_s: float = 1e-3,
        strict: bool = False,
        skip_bad: bool = False,
        realtime: bool = False,
    ) -> None:
        if dbc is None or motor_signal is None or load_signal is None:
            raise InvalidParameterError("a CAN log needs dbc, motor_signal and load_signal (--dbc, --motor-signal, --load-signal)")
        self.path = os.fspath(path)
        self._decoder = DbcDecoder(dbc, motor_signal, load_signal, motor_cpr, load_cpr, counter_signal, checksum_signal)
        self._pipeline_args = (period_s, max_skew_s, strict)
        self.skip_bad = skip_bad
        self.realtime = realtime
        self.pipeline = FramePipeline(self._decoder, *self._pipeline_args)
        self.counters: CanCounters = self.pipeline.counters
        self._reader: can.io.generic.MessageReader | None = None

    def __enter__(self) -> "CanLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file being read, if any."""
        if self._reader is not None:
            self._reader.stop()
            self._reader = None

    def files(self) -> list[Path]:
        """The files read, in order."""
        if os.path.isdir(self.path):
            return raw_log_files(self.path, [s + gz for s in CAN_LOG_SUFFIXES for gz in ("", ".gz")])
        return [Path(self.path)]

    def iter_chunks(self, size: int = 65536) -> Iterator[SampleChunk]:
        """The samples in :class:`~online_backlash.stream.SampleChunk` blocks (for ``learn_many``)."""
        return chunked(self, size)

    def __iter__(self) -> Iterator[Sample]:
        self.pipeline = pipeline = FramePipeline(self._decoder, *self._pipeline_args)
        self.counters = pipeline.counters
        feed = pipeline.feed
        for path in self.files():
            messages = self._open(path)
            if messages is None:
                continue
            index = 0
            try:
                while True:
                    try:
                        msg = next(messages)
                    except StopIteration:
                        break
                    except Exception as exc:  # noqa: BLE001 - see _open
                        self._bad(path, index, exc)
                        break
                    index += 1
                    sample = feed(msg)
                    if sample is not None:
                        yield sample
            finally:
                self.close()
        pipeline.flush()

    def _open(self, path: Path) -> Iterator[can.Message] | None:
        """An iterator over the frames of ``path``; None if it cannot be read and ``skip_bad``.

        python-can's readers raise many types on a damaged file (struct.error, zlib.error,
        BLFParseError, ValueError, IndexError, EOFError, UnicodeDecodeError, ...): all of them
        mean the file cannot be read on from there, and become LogFormatError with the frame index.
        """
        try:
            self._reader = _log_reader(path)
        except OSError as exc:
            if not path.exists():
                raise LogFormatError(path, None, f"cannot open: {exc.strerror or exc}") from exc
            self._bad(path, 0, exc)
            return None
        except Exception as exc:  # noqa: BLE001
            self._bad(path, 0, exc)
            return None
        messages = iter(can.MessageSync(self._reader) if self.realtime else self._reader)
        if isinstance(self._reader, can.BLFReader) and path.suffix.lower() == ".blf":
            return self._whole_blf(path, self._reader.file_size, messages)
        return messages

    def _whole_blf(self, path: Path, header_size: int, messages: Iterator[can.Message]) -> Iterator[can.Message]:
        """python-can's BLF reader stops quietly at a cut; the header's file size tells."""
        yield from messages
        actual = path.stat().st_size
        if header_size and actual < header_size:
            raise _Truncated(f"truncated: {actual} of the {header_size} bytes its header announces")

    def _bad(self, path: Path, index: int, exc: BaseException) -> None:
        reason = f"unreadable frame ({type(exc).__name__}: {exc})"
        if not self.skip_bad:
            raise LogFormatError(path, index, reason) from exc
        self.counters.frames += 1
        self.counters.corrupt += 1


class _Truncated(Exception):
    """Raised inside the frame iterator when a file turns out to be cut short."""


def _log_reader(path: Path) -> can.io.generic.MessageReader:
    """python-can's reader for ``path`` (by suffix, ``.gz`` looked through), times absolute.

    ASC stores times relative to its header date; ask for absolute ones, as live. The file is
    opened here (in the mode and encoding python-can would use), so that it is closed again when
    the reader rejects it, and so that ``.gz`` files get the same reader options.
    """
    suffix = log_suffix(path)
    reader = can.io.player.MESSAGE_READERS[suffix]
    options = {"relative_timestamp": False} if suffix == ".asc" else {}
    if not issubclass(reader, can.io.generic.FileIOMessageReader):
        return reader(path, **options)  # e.g. the SQLite reader opens its own database
    mode = "rt" if issubclass(reader, can.io.generic.TextIOMessageReader) else "rb"
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    file = opener(path, mode)
    try:
        return reader(file, **options)
    except BaseException:
        file.close()
        raise

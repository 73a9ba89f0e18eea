"""Recorded CAN logs (every format python-can's ``LogReader`` reads) decoded with a DBC.

Reading runs flat out in blocks of frames: python-can's reader gives the frames, their ids,
flags, times and data bytes go into numpy arrays, and :mod:`~online_backlash.drivers.blockdecode`
(checks and cantools' signal layout, CRC table from crccheck) and
:mod:`~online_backlash.drivers.blockpairing` (pairing, unwrapping, gaps; compiled) apply the
rules of the per-frame :class:`~online_backlash.drivers.pairing.FramePipeline` that the live
:class:`~online_backlash.drivers.can.CanSource` uses, so a raw log recorded live replays to the
same samples, counters and gaps. ``realtime=True`` (paced to the recorded timestamps with
python-can's :class:`can.MessageSync`), ``strict=True`` (raise at the corrupt frame) and DBCs the
block decoder does not support (messages over 8 bytes, multiplexed, float signals) take the
per-frame path.

A reader that fails (truncated or malformed file) raises :class:`LogFormatError` naming the file
and the 0-based index of the frame it could not read; with ``skip_bad=True`` the failure is
counted as one corrupt frame and that file ends there (python-can's readers cannot resume).
"""

from __future__ import annotations

import gzip
import os
from itertools import islice
from pathlib import Path
from typing import Iterator

import can
import numpy as np
from cantools.database.can import Database

from online_backlash.drivers.blockdecode import CORRUPT, SKIPPED, BlockDecoder
from online_backlash.drivers.blockpairing import BlockPipeline
from online_backlash.drivers.dbc import DbcDecoder
from online_backlash.drivers.pairing import CanCounters, FramePipeline
from online_backlash.drivers.rawlog import raw_log_files
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.replay import log_suffix
from online_backlash.stream import Sample, SampleChunk, SampleSource, chunked

#: Suffixes python-can reads (``.csv`` is ours: see :mod:`online_backlash.replay.csv`).
CAN_LOG_SUFFIXES = tuple(s for s in can.io.player.MESSAGE_READERS if s != ".csv")
#: Frames read into arrays at once on the block path.
BLOCK_FRAMES = 1024


class CanLog(SampleSource):
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
    pipeline : FramePipeline or BlockPipeline
        The pairing skew of the last iteration (``frames_per_sample``, ``skew_mean_s``, ``skew_max_s``).
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
        self.pipeline: FramePipeline | BlockPipeline = FramePipeline(self._decoder, *self._pipeline_args)
        self.counters: CanCounters = self.pipeline.counters
        self._blocks = BlockDecoder(self._decoder)
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

    @property
    def block_path(self) -> bool:
        """True when iteration takes the block path (not realtime, not strict, a DBC it supports)."""
        return self._blocks.supported and not self.realtime and not self._pipeline_args[2]

    def iter_chunks(self, size: int = 65536) -> Iterator[SampleChunk]:
        """The samples in :class:`~online_backlash.stream.SampleChunk` blocks of ``size`` (the last one shorter; for ``learn_many``)."""
        if not self.block_path:
            return chunked(self._frame_by_frame(), size)
        if size < 1:
            raise InvalidParameterError(f"chunk size must be >= 1, got {size}")
        return self._chunks(size)

    def __iter__(self) -> Iterator[Sample]:
        if not self.block_path:
            yield from self._frame_by_frame()
            return
        for time_s, motor_deg, load_deg, seq, after_gap in self._sample_arrays():
            for t, m, l, q, g in zip(time_s.tolist(), motor_deg.tolist(), load_deg.tolist(), seq.tolist(), after_gap.tolist()):
                yield Sample(t, m, l, None, None if q < 0 else q, g)

    def _chunks(self, size: int) -> Iterator[SampleChunk]:
        parts: list[tuple[np.ndarray, ...]] = []
        held = 0
        for arrays in self._sample_arrays():
            parts.append(arrays)
            held += arrays[0].shape[0]
            if held >= size:
                joined = [np.concatenate(a) for a in zip(*parts)]
                start = 0
                while held - start >= size:
                    yield _chunk(joined, start, start + size)
                    start += size
                parts, held = [tuple(a[start:] for a in joined)], held - start
        if held:
            yield _chunk([np.concatenate(a) for a in zip(*parts)], 0, held)

    def _sample_arrays(self) -> Iterator[tuple[np.ndarray, ...]]:
        """Per block of frames read: the samples as arrays (time, motor, load, seq with -1 for none, after_gap)."""
        self.pipeline = pipeline = BlockPipeline(self._decoder, self._pipeline_args[0], self._pipeline_args[1])
        self.counters = counters = pipeline.counters
        decode = self._blocks.decode
        for path in self.files():
            messages = self._open(path)
            if messages is None:
                continue
            failure: list[BaseException] = []
            frames = _until_failure(messages, failure)
            index = 0
            try:
                while True:
                    block = list(islice(frames, BLOCK_FRAMES))
                    n = len(block)
                    if n:
                        index += n
                        time_s, arrays = _frame_arrays(block)
                        del block
                        decoded = decode(*arrays)
                        counters.frames += n
                        counters.corrupt += int(np.count_nonzero(decoded.status == CORRUPT))
                        counters.skipped += int(np.count_nonzero(decoded.status == SKIPPED))
                        yield pipeline.feed(decoded, time_s)
                    if failure:
                        self._bad(path, index, failure[0])
                    if n < BLOCK_FRAMES:
                        break
            finally:
                self.close()
        pipeline.flush()

    def _frame_by_frame(self) -> Iterator[Sample]:
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


def _until_failure(messages: Iterator[can.Message], failure: list[BaseException]) -> Iterator[can.Message]:
    """The frames of ``messages`` until the reader fails; the failure is appended to ``failure``."""
    try:
        yield from messages
    except Exception as exc:  # noqa: BLE001 - see CanLog._open
        failure.append(exc)


def _frame_arrays(block: list[can.Message]) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Timestamps, and the arguments of :meth:`BlockDecoder.decode`, of a block of frames."""
    n = len(block)
    ids = np.fromiter([m.arbitration_id for m in block], np.int64, n)
    extended = np.fromiter([m.is_extended_id for m in block], np.bool_, n)
    special = np.fromiter([m.is_error_frame or m.is_remote_frame for m in block], np.bool_, n)
    time_s = np.fromiter([m.timestamp for m in block], np.float64, n)
    data = [m.data for m in block]
    lengths = np.fromiter(map(len, data), np.int64, n)
    offsets = np.cumsum(lengths) - lengths
    return time_s, (ids, extended, special, lengths, offsets, np.frombuffer(b"".join(data), np.uint8))


def _chunk(arrays: list[np.ndarray], start: int, stop: int) -> SampleChunk:
    time_s, motor_deg, load_deg, _, after_gap = (a[start:stop] for a in arrays)
    return SampleChunk(time_s, motor_deg, load_deg, np.full(stop - start, np.nan), after_gap)


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

"""Recorded CAN logs (every format python-can's ``LogReader`` reads) decoded with a DBC.

Reading runs flat out in blocks of frames: python-can's reader gives the frames, their ids,
flags, times and data bytes go into numpy arrays, and :mod:`~online_backlash.codecs.blockdecode`
(checks and cantools' signal layout, CRC table from crccheck) and
:mod:`~online_backlash.codecs.blockpairing` (pairing, unwrapping, gaps; compiled) apply the
rules of the per-frame :class:`~online_backlash.codecs.pairing.FramePipeline` (tested equal).
The live :class:`~online_backlash.drivers.can.CanSource` feeds the same pipeline with what the bus
delivered, so a raw log recorded live replays to the same samples, counters and gaps.
``realtime=True`` (paced to the recorded timestamps with python-can's :class:`can.MessageSync`),
``strict=True`` (raise at the corrupt frame) and DBCs the block decoder does not support
(messages over 8 bytes, multiplexed, float signals) take the per-frame path
(:func:`~online_backlash.codecs.blockpairing.make_pipeline` chooses).

A reader that fails (truncated or malformed file) raises :class:`LogFormatError` naming the file
and the 0-based index of the frame it could not read; with ``skip_bad=True`` the failure is
counted as one corrupt frame and that file ends there (python-can's readers cannot resume). A
``.blf`` that is empty or not BLF at all is refused before python-can reads it, and one shorter
than its header says is truncated (:func:`blf_cut`: python-can stops quietly at the cut).
"""

from __future__ import annotations

import gzip
import os
from collections import Counter
from collections.abc import Iterator
from itertools import islice
from pathlib import Path

import can

from online_backlash.codecs.blockpairing import BlockPipeline, make_pipeline
from online_backlash.codecs.options import DEFAULT_COUNTS, DEFAULT_FRAMES, CanDecoding, Counts, FrameRules
from online_backlash.codecs.pairing import CanCounters, CanPipeline
from online_backlash.codecs.rawfiles import raw_log_files
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.stream import SampleChunk, SampleSource, rechunk

from .paths import file_suffix
from .signatures import check_signature
from .summary import CanIdInfo, FileSummary

#: Suffixes python-can reads (``.csv`` is ours: see :mod:`online_backlash.replay.csv`).
CAN_LOG_SUFFIXES = tuple(s for s in can.io.player.MESSAGE_READERS if s != ".csv")
#: Frames read and decoded at once (one frame at a time when paced to the recorded times).
BLOCK_FRAMES = 1024
#: Samples per block of :meth:`CanLog.iter_chunks` when no ``max_samples`` is asked for.
CHUNK_SAMPLES = 65536


class CanLog(SampleSource):
    """A recorded CAN log (or a directory of them, in name order) as a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    path : path
        A ``.asc``, ``.blf``, ``.log`` (candump), ``.trc``, ``.db`` or ``.mf4`` file (``.gz`` too),
        or a directory whose CAN log files are read in name order (a ``--raw-log`` directory).
    decoding : CanDecoding
        The DBC and its signals (:class:`~online_backlash.codecs.dbc.DbcDecoder`), ``max_skew_s`` for pairing by time
        (:class:`~online_backlash.codecs.pairing.FramePipeline`).
    counts : Counts
        Encoder counts per revolution (None: the DBC's).
    frames : FrameRules
        The nominal period for the gap rule (learnt if None) and ``strict`` (raise at a corrupt frame).
    skip_bad : bool
        Count a reader failure as corrupt and end that file instead of raising.
    realtime : bool
        Pace to the recorded timestamps.

    Attributes
    ----------
    counters : CanCounters
        Reconcile at the end of iteration (see :mod:`~online_backlash.codecs.pairing`).
    pipeline : CanPipeline
        The pairing skew of the last iteration (``frames_per_sample``, ``skew_mean_s``, ``skew_max_s``).
    block_path : bool
        True when iteration takes the block path (not realtime, not strict, a DBC it supports).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        decoding: CanDecoding,
        *,
        counts: Counts = DEFAULT_COUNTS,
        frames: FrameRules = DEFAULT_FRAMES,
        skip_bad: bool = False,
        realtime: bool = False,
    ) -> None:
        self._decode_with(decoding, counts)
        self._frame_args = (frames.period_s, decoding.max_skew_s, frames.strict)
        self._setup(path, skip_bad, realtime)

    def _decode_with(self, decoding: CanDecoding, counts: Counts) -> None:
        """The frames' decoder: the DBC's signals (a subclass with other frame rules overrides this)."""
        if decoding.dbc is None or decoding.motor_signal is None or decoding.load_signal is None:
            raise InvalidParameterError(
                "a CAN log needs dbc, motor_signal and load_signal (--dbc, --motor-signal, --load-signal)"
            )
        self.decoder = decoding.dbc_decoder(counts)

    def _setup(self, path: str | os.PathLike[str], skip_bad: bool, realtime: bool) -> None:
        """The reading state every CAN log shares (a subclass with other frame rules calls this and overrides
        :meth:`_new_pipeline`)."""
        self.path = os.fspath(path)
        self.skip_bad = skip_bad
        self.realtime = realtime
        self.pipeline: CanPipeline = self._new_pipeline()
        self.counters: CanCounters = self.pipeline.counters
        self.block_path = isinstance(self.pipeline, BlockPipeline)
        self._reader: can.io.generic.MessageReader | None = None

    def _new_pipeline(self) -> CanPipeline:
        """A fresh pipeline for one pass over the files: the DBC rules (block path where it applies)."""
        return make_pipeline(self.decoder, *self._frame_args, self.realtime)

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

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """The samples in :class:`~online_backlash.stream.SampleChunk` blocks of ``max_samples``
        (the last one shorter; None: :data:`CHUNK_SAMPLES`, or, paced to the recorded times, what
        each frame completes), with the frames' rolling counters in ``seq`` (-1 without one)."""
        if max_samples is None and not self.realtime:
            max_samples = CHUNK_SAMPLES
        return rechunk(self._blocks(), max_samples)

    def _blocks(self) -> Iterator[SampleChunk]:
        """Per block of frames read: the samples they complete."""
        self.pipeline = pipeline = self._new_pipeline()
        self.counters = pipeline.counters
        per_read = 1 if self.realtime else BLOCK_FRAMES
        for path in self.files():
            messages = self._open(path)
            if messages is None:
                continue
            failure: list[BaseException] = []
            frames = _until_failure(messages, failure)
            index = 0
            try:
                while True:
                    block = list(islice(frames, per_read))
                    index += len(block)
                    if block:
                        yield pipeline.feed_frames(block)
                    if failure:
                        self._bad(path, index, failure[0])
                    if len(block) < per_read:
                        break
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
            self._reader = open_can_log(path)
        except LogFormatError:  # empty, or not of its format at all
            if not self.skip_bad:
                raise
            self._count_bad()
            return None
        except OSError as exc:
            if not path.exists():
                raise LogFormatError(path, None, f"cannot open: {exc.strerror or exc}") from exc
            self._bad(path, 0, exc)
            return None
        except Exception as exc:
            self._bad(path, 0, exc)
            return None
        messages = iter(can.MessageSync(self._reader) if self.realtime else self._reader)
        if isinstance(self._reader, can.BLFReader):
            return self._whole_blf(path, self._reader, messages)
        return messages

    def _whole_blf(self, path: Path, reader: can.BLFReader, messages: Iterator[can.Message]) -> Iterator[can.Message]:
        """python-can's BLF reader stops quietly at a cut; the header's file size tells (:func:`blf_cut`)."""
        yield from messages
        cut = blf_cut(path, reader)
        if cut is not None:
            raise _Truncated(f"{cut}: the frames after the cut are lost")

    def _bad(self, path: Path, index: int, exc: BaseException) -> None:
        reason = str(exc) if isinstance(exc, _Truncated) else f"unreadable frame ({type(exc).__name__}: {exc})"
        if not self.skip_bad:
            raise LogFormatError(path, index, reason) from exc
        self._count_bad()

    def _count_bad(self) -> None:
        """A file that failed, counted as one corrupt frame (``skip_bad``)."""
        self.counters.frames += 1
        self.counters.corrupt += 1


def _until_failure(messages: Iterator[can.Message], failure: list[BaseException]) -> Iterator[can.Message]:
    """The frames of ``messages`` until the reader fails; the failure is appended to ``failure``."""
    try:
        yield from messages
    except Exception as exc:
        failure.append(exc)


class _Truncated(Exception):
    """Raised inside the frame iterator when a file turns out to be cut short."""


def blf_cut(path: Path, reader: can.io.generic.MessageReader) -> str | None:
    """Why a BLF file read by ``reader`` (python-can's, which stops quietly at a cut) is truncated: its size is
    less than its header announces; None for a whole file or another format."""
    if not isinstance(reader, can.BLFReader) or path.name.lower().endswith(".gz"):
        return None
    actual, announced = path.stat().st_size, reader.file_size
    if not announced or actual >= announced:
        return None
    return f"truncated: {actual} of the {announced} bytes its header announces"


def open_can_log(path: Path) -> can.io.generic.MessageReader:
    """python-can's reader for ``path`` (by suffix, ``.gz`` looked through), times absolute; a ``.blf`` that is
    empty or not BLF raises LogFormatError saying so (:func:`~online_backlash.replay.signatures.check_signature`).

    ASC stores times relative to its header date; ask for absolute ones, as live. The file is
    opened here (in the mode and encoding python-can would use), so that it is closed again when
    the reader rejects it, and so that ``.gz`` files get the same reader options.
    """
    suffix = file_suffix(path)
    if suffix == ".blf" and not path.name.lower().endswith(".gz"):
        check_signature(path, "BLF")
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


def describe(path: str, dbc: str | os.PathLike[str] | None = None) -> FileSummary:
    """Frames per CAN ID of a python-can log, with the DBC's message names (a truncated BLF: up to the cut)."""
    names = _dbc_names(dbc) if dbc is not None else {}
    counts: Counter[tuple[int, bool]] = Counter()
    first: dict[tuple[int, bool], float] = {}
    last: dict[tuple[int, bool], float] = {}
    index = 0
    try:
        with open_can_log(Path(path)) as reader:
            for index, message in enumerate(reader):  # noqa: B007 (index names the failing frame)
                if message.is_error_frame:
                    continue
                key = (message.arbitration_id, message.is_extended_id)
                counts[key] += 1
                first.setdefault(key, message.timestamp)
                last[key] = message.timestamp
        cut = blf_cut(Path(path), reader)
    except LogFormatError:
        raise
    except Exception as exc:  # every python-can reader fails its own way on a damaged file
        raise LogFormatError(path, index, f"cannot read the CAN log ({type(exc).__name__}: {exc})") from exc
    ids = []
    for (can_id, extended), n in sorted(counts.items()):
        span = last[(can_id, extended)] - first[(can_id, extended)]
        rate = float(f"{(n - 1) / span:.6g}") if n > 1 and span > 0 else None
        ids.append(CanIdInfo(can_id, extended, n, rate, names.get((can_id, extended))))
    return FileSummary(path, "can", can_ids=ids, frames=sum(counts.values()), truncated=cut)


def _dbc_names(dbc: str | os.PathLike[str]) -> dict[tuple[int, bool], str]:
    import cantools

    try:
        database = cantools.database.load_file(os.fspath(dbc))
    except Exception as exc:  # cantools raises its own parse errors and OSErrors
        raise LogFormatError(dbc, None, f"cannot load the DBC ({type(exc).__name__}: {exc})") from exc
    return {(m.frame_id, m.is_extended_frame): m.name for m in getattr(database, "messages", [])}

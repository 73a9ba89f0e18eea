"""Serial captures (the raw bytes a live :class:`~online_backlash.drivers.serial.SerialSource`
appended to ``--raw-log DIR``) replayed through the same parser.

A capture holds every byte received, garbage included, so corrupt frames inside it are counted
exactly as they were live. Only a capture that ends inside a frame is malformed: that raises
:class:`LogFormatError` naming the file and the frame index, unless ``skip_bad=True`` (then it
is one more corrupt frame).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from online_backlash.codecs.options import DEFAULT_COUNTS, DEFAULT_FRAMES, Counts, FrameRules, gather_options
from online_backlash.codecs.rawfiles import SERIAL_SUFFIX, raw_log_files
from online_backlash.codecs.serialframes import FrameParser, make_parser
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.stream import SampleChunk, SampleSource, StreamCounters, rechunk

from .formats import LogFormat
from .options import BadRows, Pace, SerialFraming, Timing

#: Samples per block of :meth:`SerialCapture.iter_chunks` when no ``max_samples`` is asked for.
CHUNK_SAMPLES = 65536


class SerialCapture(SampleSource):
    """A serial capture file (or a ``--raw-log`` directory of them, concatenated in name order).

    Parameters
    ----------
    path : path
        A ``.serial`` file or a directory of them.
    serial_format : {"ascii", "binary"}
        How the bytes are framed (required: a capture is bytes only).
    counts : Counts
        Counts per revolution (``binary`` only).
    frames : FrameRules
        The nominal period for the gap rule (learnt if None) and ``strict`` (raise at a corrupt frame); see
        :func:`~online_backlash.codecs.serialframes.make_parser`.
    skip_bad : bool
        Count a truncated last frame as corrupt instead of raising.
    realtime : bool
        Pace to the samples' timestamps.
    block_bytes : int
        Bytes read at once.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        serial_format: str | None = None,
        *,
        counts: Counts = DEFAULT_COUNTS,
        frames: FrameRules = DEFAULT_FRAMES,
        skip_bad: bool = False,
        realtime: bool = False,
        block_bytes: int = 1 << 16,
    ) -> None:
        if serial_format is None:
            raise InvalidParameterError("a serial capture needs serial_format 'ascii' or 'binary' (--serial-format)")
        self.path = os.fspath(path)
        self._parser_args = (serial_format, counts.kwargs() | frames.kwargs())
        self.parser: FrameParser = self._new_parser()
        self.counters: StreamCounters = self.parser.counters
        self.skip_bad = skip_bad
        self.realtime = realtime
        self.block_bytes = int(block_bytes)

    def _new_parser(self) -> FrameParser:
        serial_format, options = self._parser_args
        return make_parser(serial_format, **options)

    def close(self) -> None:
        """Nothing stays open between iterations."""

    def files(self) -> list[Path]:
        """The files read, in order."""
        if os.path.isdir(self.path):
            return raw_log_files(self.path, [SERIAL_SUFFIX])
        return [Path(self.path)]

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """The samples in :class:`~online_backlash.stream.SampleChunk` blocks of ``max_samples``
        (the last one shorter; None: :data:`CHUNK_SAMPLES`, or, paced, what each read completes)."""
        if max_samples is None and not self.realtime:
            max_samples = CHUNK_SAMPLES
        return rechunk(self._blocks(), max_samples)

    def _blocks(self) -> Iterator[SampleChunk]:
        """Per block of bytes read: the samples it completes."""
        self.parser = parser = self._new_parser()
        self.counters = parser.counters
        pace = _Pacer() if self.realtime else None
        files = self.files()
        for path in files:
            try:
                f = open(path, "rb")
            except OSError as exc:
                raise LogFormatError(path, None, f"cannot open: {exc.strerror or exc}") from exc
            with f:
                while block := f.read(self.block_bytes):
                    chunk = parser.feed_chunk(block)
                    if pace is not None:
                        yield from pace.chunks(chunk)
                    else:
                        yield chunk
        if parser.finish():
            if not self.skip_bad:
                raise LogFormatError(files[-1], self.counters.frames, "capture ends inside a frame (truncated)")
            self.counters.frames += 1
            self.counters.corrupt += 1


class _Pacer:
    """Sleep so that samples come out at their recorded spacing (seconds)."""

    def __init__(self) -> None:
        self._offset: float | None = None

    def __call__(self, time_s: float) -> None:
        now = time.perf_counter()
        if self._offset is None:
            self._offset = now - time_s
            return
        delay = time_s + self._offset - now
        if delay > 0:
            time.sleep(delay)

    def chunks(self, chunk: SampleChunk) -> Iterator[SampleChunk]:
        """The samples of ``chunk`` one at a time, each when its time has come."""
        for i, time_s in enumerate(chunk.time_s.tolist()):
            self(time_s)
            yield chunk.slice(i, i + 1)


def _open(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A serial capture; ``options`` are the fields of its options
    (:func:`~online_backlash.codecs.options.gather_options`)."""
    return SerialCapture(path, **gather_options(options, counts=Counts, frames=FrameRules))


#: Raw serial captures (``listen serial --raw-log``).
SERIAL = LogFormat(
    "serial",
    (SERIAL_SUFFIX,),
    _open,
    (SerialFraming, Counts, BadRows, Pace, Timing),
    directories=True,
    title="a serial capture, with --serial-format",
)

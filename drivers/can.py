r"""Live CAN: a python-can Bus, a Notifier, the raw writer first, then the decoder.

::

    Bus --Notifier--> RawCanLog (python-can writer, --raw-log DIR)     first: nothing lost
                  \-> _RowListener (DbcDecoder + FramePipeline) -> queue of rows
                      -> CanSource.iter_chunks: the rows that arrived since the last receive,
                         as the arrays of one SampleChunk (no Sample objects)

On a stop (Ctrl-C, ``duration_s``) the notifier ends, and the frames still waiting on the bus go
through the same two before the raw log is closed: a run's summary has every frame that had arrived.

The notifier thread receives and decodes frame by frame; the consumer takes blocks of samples in
its own thread. Live, a frame comes at a time, for which the per-frame path costs about 16 us and
the block path of replay (:class:`online_backlash.replay.canlog.CanLog`) about 300 us a call
(numpy's fixed costs); the two give the same samples, counters and gaps
(``tests/test_can_blocks.py``), so a raw log replays to what was seen live.
"""

from __future__ import annotations

import queue
from collections.abc import Iterator
from typing import Any, Protocol

import can

from online_backlash.codecs.options import DEFAULT_COUNTS, DEFAULT_FRAMES, CanDecoding, Counts, FrameRules
from online_backlash.codecs.pairing import CanCounters, CanPipeline, FramePipeline
from online_backlash.errors import BacklashError, SourceError
from online_backlash.stream import Row, SampleChunk, rows_to_chunk

from .live import DEFAULT_LIVE, LiveOptions, LiveSource
from .rawlog import RawCanLog

_POLL_S = 0.05
#: put on the receive queue by :meth:`CanSource.request_stop` to wake the wait for a frame
_WAKE = object()


def open_bus(interface: str, channel: Any, bitrate: int | None = None, **config: Any) -> can.BusABC:
    """A python-can Bus (any interface python-can supports); errors become SourceError."""
    if bitrate is not None:
        config["bitrate"] = bitrate
    try:
        return can.Bus(interface=interface, channel=channel, **config)
    except (can.CanError, ValueError, ImportError, OSError) as exc:
        raise SourceError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from exc


class RowPipeline(Protocol):
    """What the notifier thread feeds: one frame in, the checked sample it completes (a row) out;
    :class:`~online_backlash.codecs.pairing.FramePipeline` (DBC) and
    :class:`~online_backlash.codecs.canopen.SyncPipeline` (CANopen) are ones."""

    counters: CanCounters

    def feed_row(self, msg: can.Message) -> Row | None: ...

    def flush(self) -> None: ...


class _RowListener(can.Listener):
    """Decode in the notifier thread; hand the checked samples as rows (or the error that stopped it) to the
    consumer."""

    def __init__(self, pipeline: RowPipeline, out: queue.SimpleQueue) -> None:
        self.pipeline = pipeline
        self.out = out

    def on_message_received(self, msg: can.Message) -> None:
        row = self.pipeline.feed_row(msg)
        if row is not None:
            self.out.put(row)

    def on_error(self, exc: Exception) -> None:
        self.out.put(exc)


class _InOrder(can.Listener):
    """The notifier's one listener: each frame to the raw writer first (if any), then to the decoder. Stopping
    the notifier leaves them open (this listener's ``stop`` does nothing), so that :meth:`CanSource.stop`
    can put the frames still waiting on the bus through the same two before it closes the raw log."""

    def __init__(self, raw_log: RawCanLog | None, rows: _RowListener) -> None:
        self.raw_log = raw_log
        self.rows = rows

    def on_message_received(self, msg: can.Message) -> None:
        if self.raw_log is not None:
            self.raw_log.on_message_received(msg)
        self.rows.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        self.rows.on_error(exc)


class CanSource(LiveSource):
    """Samples from a live CAN bus, decoded with a DBC; a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    bus : can.BusABC
        An open bus (see :func:`open_bus`); shut down by :meth:`close` if ``live.own_bus``.
    decoding, counts, frames
        How the frames become samples, as a recorded log's (:class:`~online_backlash.replay.canlog.CanLog`):
        :class:`~online_backlash.codecs.options.CanDecoding`, :class:`~online_backlash.codecs.options.Counts`,
        :class:`~online_backlash.codecs.options.FrameRules`.
    live : LiveOptions
        The raw log (written first), ``duration_s``, ``timeout_s``, ``own_bus``.

    Attributes
    ----------
    counters : CanCounters
        ``frames`` counts every frame the bus delivered; they reconcile after close.
    pipeline : CanPipeline
        Pairing skew (``skew_mean_s``, ``skew_max_s``) and frames per sample.
    raw_log : RawCanLog or None
    max_batch : int
        Most samples handed on per receive (a block of ``iter_chunks``).
    """

    max_batch = 4096

    def __init__(
        self,
        bus: can.BusABC,
        decoding: CanDecoding,
        *,
        counts: Counts = DEFAULT_COUNTS,
        frames: FrameRules = DEFAULT_FRAMES,
        live: LiveOptions = DEFAULT_LIVE,
    ) -> None:
        try:
            pipeline = self._new_pipeline(decoding, counts, frames)
        except BaseException:
            if live.own_bus:
                bus.shutdown()
            raise
        self._listen(bus, pipeline, live)

    def _new_pipeline(self, decoding: CanDecoding, counts: Counts, frames: FrameRules) -> RowPipeline:
        """The frame rules: the DBC's signals paired frame by frame (a subclass with other frame rules overrides
        this)."""
        pipeline = FramePipeline(decoding.dbc_decoder(counts), frames.period_s, decoding.max_skew_s, frames.strict)
        self.pipeline: CanPipeline = pipeline
        return pipeline

    def _listen(self, bus: can.BusABC, pipeline: RowPipeline, live: LiveOptions) -> None:
        """Start receiving: the raw writer first, then ``pipeline`` in the notifier thread."""
        self._rows = pipeline
        self.counters: CanCounters = pipeline.counters
        self.bus = bus
        self.own_bus = live.own_bus
        self._start(live)
        self.raw_log = RawCanLog(live.raw_log_dir, live.raw_format) if live.raw_log_dir is not None else None
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._receiver = _InOrder(self.raw_log, _RowListener(pipeline, self._queue))
        self._notifier = can.Notifier(bus, [self._receiver], timeout=_POLL_S)
        self._closed = False

    def request_stop(self) -> None:
        """Ask the iteration to stop soon, and wake the wait for a frame: safe from a signal handler
        (``SimpleQueue.put`` is reentrant). CPython's ``SimpleQueue.get(timeout=...)`` waits for ever
        when a signal handler that returns normally (Ctrl-C here) ran after the wait's deadline had
        passed: on a bus gone quiet nothing else would end that wait."""
        super().request_stop()
        self._queue.put(_WAKE)

    def _receive(self) -> SampleChunk | None:
        """Wait for a sample, then take those queued behind it (at most ``max_batch``), as one block."""
        try:
            item = self._queue.get(timeout=_POLL_S)
        except queue.Empty:
            return None
        if item is _WAKE:
            return None
        return rows_to_chunk(self._drain([_checked(item)]))

    def _where(self) -> str:
        return f"CAN {self.bus.channel_info}"

    def _leftovers(self) -> Iterator[SampleChunk]:
        """After :meth:`stop` (or ``duration_s``), the samples still queued."""
        while rows := self._drain([]):
            yield rows_to_chunk(rows)

    def _drain(self, rows: list[Row]) -> list[Row]:
        get = self._queue.get_nowait
        while len(rows) < self.max_batch:
            try:
                item = get()
            except queue.Empty:
                break
            if item is not _WAKE:
                rows.append(_checked(item))
        return rows

    def stop(self) -> None:
        """Stop receiving: stop the notifier, take the frames still waiting on the bus, close the raw log,
        count frames left unpaired."""
        if self._stopped:
            return
        self._stopped = True
        self._notifier.stop()
        self._take_waiting()
        if self.raw_log is not None:
            self.raw_log.stop()
        self._rows.flush()

    def _take_waiting(self) -> None:
        """The frames that had arrived when the stop came but were not read yet (a Ctrl-C right after the
        last frames, ``duration_s`` on a busy bus): logged and decoded like the others, so the run's
        summary has them. Decoding (about 16 us a frame) outpaces any CAN bus, so this ends; a bus that
        fails here is reported as the notifier reports it."""
        try:
            while (msg := self.bus.recv(0)) is not None:
                self._receiver.on_message_received(msg)
        except Exception as exc:  # as can.Notifier: any failure of the bus goes to the consumer
            self._receiver.on_error(exc)

    def close(self) -> None:
        """:meth:`stop`, then shut the bus down (if owned); the counters then reconcile."""
        self.stop()
        if self.own_bus and not self._closed:
            self.bus.shutdown()
        self._closed = True


def _checked(item: Row | Exception) -> Row:
    """A queued row, or the error the notifier thread hit, re-raised here (as a SourceError
    unless it is one of ours already: a strict FrameError, say)."""
    if isinstance(item, BacklashError):
        raise item
    if isinstance(item, Exception):
        raise SourceError(f"CAN reception stopped: {type(item).__name__}: {item}") from item
    return item

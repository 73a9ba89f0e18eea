"""Live serial: a pyserial port (``serial_for_url``: real ports, ``loop://``, ``socket://``, ...).

Bytes are appended verbatim to the raw capture (``raw_log_dir``) *before* they are parsed, and
the parser (:mod:`~online_backlash.codecs.serialframes`) resynchronises after garbage. Replaying
the capture with :class:`online_backlash.replay.serialcapture.SerialCapture` feeds the same
bytes to the same parser, so it gives the same samples.
"""

from __future__ import annotations

import serial

from online_backlash.codecs.options import DEFAULT_COUNTS, DEFAULT_FRAMES, Counts, FrameRules
from online_backlash.codecs.serialframes import make_parser
from online_backlash.errors import SourceError
from online_backlash.stream import SampleChunk

from .live import DEFAULT_LIVE, LiveOptions, LiveSource
from .rawlog import RawByteLog

_POLL_S = 0.05


def open_port(url: str, baudrate: int = 115200) -> serial.SerialBase:
    """Open ``url`` with :func:`serial.serial_for_url`; errors become SourceError."""
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=_POLL_S)
    except (serial.SerialException, ValueError) as exc:
        raise SourceError(f"cannot open serial port {url!r}: {exc}") from exc


class SerialSource(LiveSource):
    """Samples from a serial port; a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    port : str or serial port
        A URL for :func:`serial.serial_for_url` (``/dev/ttyUSB0``, ``loop://``), or an open port.
    baudrate : int
    serial_format : {"ascii", "binary"}
        See :mod:`~online_backlash.codecs.serialframes`.
    counts : Counts
        Counts per revolution (``binary`` only).
    frames : FrameRules
        The nominal period for the gap rule (learnt if None) and ``strict``; see
        :class:`~online_backlash.codecs.serialframes.FrameParser`.
    live : LiveOptions
        The raw capture (written first), ``duration_s``, ``timeout_s`` (nothing received for so long, seconds).

    Attributes
    ----------
    counters : StreamCounters
        ``frames == samples + corrupt`` after :meth:`close` (a partial last frame counts as corrupt).
    bytes_read : int
        Bytes received (and captured) so far.
    """

    def __init__(
        self,
        port: str | serial.SerialBase,
        baudrate: int = 115200,
        serial_format: str = "ascii",
        *,
        counts: Counts = DEFAULT_COUNTS,
        frames: FrameRules = DEFAULT_FRAMES,
        live: LiveOptions = DEFAULT_LIVE,
    ) -> None:
        self.parser = make_parser(serial_format, **counts.kwargs(), **frames.kwargs())
        self.counters = self.parser.counters
        self.port = open_port(port, baudrate) if isinstance(port, str) else port
        self._start(live)
        self.raw_log = RawByteLog(live.raw_log_dir) if live.raw_log_dir is not None else None
        self.bytes_read = 0

    def _receive(self) -> SampleChunk | None:
        return self.poll()

    def _where(self) -> str:
        return f"serial port {self.port.name!r}"

    def poll(self) -> SampleChunk | None:
        """Read what has arrived (waiting at most the port timeout), capture it, parse it.

        Returns the samples completed as one block (possibly empty), or None if no byte arrived.
        """
        try:
            data = self.port.read(max(1, self.port.in_waiting))
        except (serial.SerialException, OSError) as exc:
            raise SourceError(f"serial port {self.port.name!r} failed: {exc}") from exc
        if not data:
            return None
        if self.raw_log is not None:
            self.raw_log.write(data)
        self.bytes_read += len(data)
        return self.parser.feed_chunk(data)

    def stop(self) -> None:
        """Stop reading; a partial last frame is counted as one corrupt frame."""
        if self._stopped:
            return
        self._stopped = True
        if self.parser.finish():
            self.counters.frames += 1
            self.counters.corrupt += 1

    def close(self) -> None:
        """:meth:`stop`, close the capture and the port."""
        self.stop()
        if self.raw_log is not None:
            self.raw_log.close()
        self.port.close()

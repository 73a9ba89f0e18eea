"""What the live sources share: the receive loop that yields what has arrived, until stopped.

:class:`LiveSource` runs the receive loop of :class:`~online_backlash.drivers.can.CanSource` and
:class:`~online_backlash.drivers.serial.SerialSource`: it ends on :meth:`LiveSource.request_stop`
(safe from a signal handler or another thread) or after ``duration_s`` seconds, and raises
:class:`~online_backlash.errors.SourceTimeoutError` when nothing arrives for ``timeout_s``
seconds. A subclass says how to receive (:meth:`LiveSource._receive`: a block of samples, as
arrays), how to stop and close, and what is still pending after the stop (:meth:`LiveSource._leftovers`).
"""

from __future__ import annotations

import os
import time
from abc import abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass

from online_backlash.errors import SourceTimeoutError
from online_backlash.stream import SampleChunk, SampleSource, rechunk

#: The formats of a raw CAN log (python-can writers).
CAN_RAW_FORMATS = ("blf", "asc", "log")


@dataclass(frozen=True)
class LiveOptions:
    """What a live source is told besides its frame rules (:mod:`online_backlash.codecs.options`).

    Attributes
    ----------
    raw_log_dir : path, optional
        Write every frame or byte received here first (:mod:`~online_backlash.drivers.rawlog`).
    raw_format : {"blf", "asc", "log"}
        The format of a raw CAN log (a serial capture is the bytes as received).
    duration_s : float, optional
        Stop iterating after this many seconds.
    timeout_s : float, optional
        Raise :class:`~online_backlash.errors.SourceTimeoutError` when nothing arrives for this long, seconds.
    own_bus : bool
        Shut a CAN bus down on close (a serial port is always closed).
    """

    raw_log_dir: str | os.PathLike[str] | None = None
    raw_format: str = "blf"
    duration_s: float | None = None
    timeout_s: float | None = None
    own_bus: bool = True


#: No raw log, no duration or timeout, the bus shut down on close.
DEFAULT_LIVE = LiveOptions()


class LiveSource(SampleSource):
    """Base of the live sources; subclasses call :meth:`_start` with their :class:`LiveOptions` and implement
    ``_receive``, ``_where``, ``stop`` and ``close``."""

    duration_s: float | None
    timeout_s: float | None
    _stop_requested: bool
    _stopped: bool

    def _start(self, live: LiveOptions) -> None:
        """The receive loop's state: ``duration_s`` and ``timeout_s`` of ``live``, not stopped."""
        self.duration_s = live.duration_s
        self.timeout_s = live.timeout_s
        self._stop_requested = False
        self._stopped = False

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """Whatever has arrived, one :class:`~online_backlash.stream.SampleChunk` per receive (None)
        or in blocks of ``max_samples``: the live fast path of ``learn_many``, until :meth:`stop`,
        ``duration_s`` or ``timeout_s``."""
        chunks = self._chunks()
        if max_samples is None:
            return chunks
        return (part for chunk in chunks for part in rechunk([chunk], max_samples))

    def request_stop(self) -> None:
        """Ask the iteration to stop soon (safe from a signal handler or another thread)."""
        self._stop_requested = True

    @abstractmethod
    def stop(self) -> None:
        """Stop receiving (idempotent); the counters then reconcile."""

    @abstractmethod
    def _receive(self) -> SampleChunk | None:
        """Wait briefly for data: the samples it completed (maybe none), or None if nothing arrived."""

    @abstractmethod
    def _where(self) -> str:
        """What the timeout message names: ``"nothing received ... on <this>"``."""

    def _leftovers(self) -> Iterator[SampleChunk]:
        """Samples still pending after :meth:`stop` (none by default)."""
        return iter(())

    def _chunks(self) -> Iterator[SampleChunk]:
        deadline = None if self.duration_s is None else time.monotonic() + self.duration_s
        last = time.monotonic()
        while not self._stopped:
            if self._stop_requested or (deadline is not None and time.monotonic() >= deadline):
                self.stop()
                break
            got = self._receive()
            if got is None:
                if self.timeout_s is not None and time.monotonic() - last > self.timeout_s:
                    raise SourceTimeoutError(f"nothing received for {self.timeout_s} s on {self._where()}")
                continue
            last = time.monotonic()
            if len(got):
                yield got
        yield from self._leftovers()

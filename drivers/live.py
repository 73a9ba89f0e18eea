"""What the live sources share: a context manager that yields what has arrived, until stopped.

:class:`LiveSource` runs the receive loop of :class:`~online_backlash.drivers.can.CanSource` and
:class:`~online_backlash.drivers.serial.SerialSource`: it ends on :meth:`LiveSource.request_stop`
(safe from a signal handler or another thread) or after ``duration_s`` seconds, and raises
:class:`~online_backlash.errors.SourceTimeoutError` when nothing arrives for ``timeout_s``
seconds. A subclass says how to receive (:meth:`LiveSource._receive`), how to stop and close, and
what is still pending after the stop (:meth:`LiveSource._leftovers`).
"""

from __future__ import annotations

import time
from typing import Iterator

from online_backlash.errors import SourceTimeoutError
from online_backlash.stream import Sample, SampleChunk, SampleSource, chunked


class LiveSource(SampleSource):
    """Base of the live sources; subclasses set ``duration_s``, ``timeout_s`` (seconds or None),
    ``_stop_requested = _stopped = False`` and implement ``_receive``, ``_where``, ``stop`` and ``close``."""

    duration_s: float | None
    timeout_s: float | None
    _stop_requested: bool
    _stopped: bool

    def __enter__(self) -> "LiveSource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[Sample]:
        """Samples as they arrive, until :meth:`stop`, ``duration_s`` or ``timeout_s``."""
        for batch in self._batches():
            yield from batch

    def iter_chunks(self) -> Iterator[SampleChunk]:
        """Whatever has arrived, as one :class:`~online_backlash.stream.SampleChunk` per receive:
        the live fast path of ``learn_many``, with no waiting to fill a block."""
        for batch in self._batches():
            yield from chunked(batch, len(batch))

    def request_stop(self) -> None:
        """Ask the iteration to stop soon (safe from a signal handler or another thread)."""
        self._stop_requested = True

    def stop(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _receive(self) -> list[Sample] | None:  # pragma: no cover - abstract
        """Wait briefly for data: the samples it completed (maybe none), or None if nothing arrived."""
        raise NotImplementedError

    def _where(self) -> str:  # pragma: no cover - abstract
        """What the timeout message names: ``"no CAN sample ... on <this>"``."""
        raise NotImplementedError

    def _leftovers(self) -> Iterator[list[Sample]]:
        """Samples still pending after :meth:`stop` (none by default)."""
        return iter(())

    def _batches(self) -> Iterator[list[Sample]]:
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
            if got:
                yield got
        yield from self._leftovers()

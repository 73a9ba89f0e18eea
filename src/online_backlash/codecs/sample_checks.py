"""The last checks before a sample leaves any source: finite values, time order, gaps.

Shared by the CAN pipeline and the serial parsers so that every adapter applies the same rules:
a non-finite value or a time that goes backwards makes the frame(s) corrupt (never yielded), and
a gap (counter jump, or a step longer than three nominal periods) is counted with its time and
length and flagged on the next sample (``after_gap=True``).
"""

from __future__ import annotations

import math

from online_backlash.errors import FrameError
from online_backlash.stream import Row, StreamCounters

from .gaps import CounterClock, GapDetector


class SampleAssembler:
    """Check readings and count them into ``counters``.

    Parameters
    ----------
    counters : StreamCounters
        Updated in place (``samples``, ``corrupt``, ``gaps``).
    counter_modulus : int or None
        Wrap of the source's sequence counter (None: gaps from time steps only).
    period_s : float or None
        Nominal sample period, seconds (None: learnt). Given, with a counter, the rows carry the
        counter's time (:class:`~online_backlash.codecs.gaps.CounterClock`) instead of the timestamps.
    strict : bool
        Raise FrameError instead of counting a bad reading as corrupt.
    """

    def __init__(
        self, counters: StreamCounters, counter_modulus: int | None, period_s: float | None, strict: bool
    ) -> None:
        self.counters = counters
        self.strict = strict
        self.gaps = GapDetector(counter_modulus, period_s)
        # with a counter and a given period, a sample's time is the counter's (the gap rule reads the timestamps)
        self.clock = (
            CounterClock(counter_modulus, period_s) if counter_modulus is not None and period_s is not None else None
        )
        self._last_time = -math.inf

    def accept(
        self, time_s: float, motor_deg: float, load_deg: float, seq: int | None, n_frames: int = 1
    ) -> bool | None:
        """Check one sample (seconds, degrees): None if it is corrupt (``n_frames`` counted), else
        whether a gap precedes it (``after_gap``); the sample is then counted."""
        if not (math.isfinite(time_s) and math.isfinite(motor_deg) and math.isfinite(load_deg)):
            self._corrupt("non-finite value", n_frames)
            return None
        if time_s < self._last_time:
            self._corrupt(f"time goes backwards ({time_s!r} s after {self._last_time!r} s)", n_frames)
            return None
        self._last_time = time_s
        gap = self.gaps.check(time_s, seq)
        if gap is not None:
            self.counters.report_gap(gap)
        self.counters.samples += 1
        return gap is not None

    def row(self, time_s: float, motor_deg: float, load_deg: float, seq: int | None, n_frames: int = 1) -> Row | None:
        """The checked sample of these readings (degrees, seconds) as a row, or None if it is corrupt (see
        :meth:`accept`)."""
        after_gap = self.accept(time_s, motor_deg, load_deg, seq, n_frames)
        if after_gap is None:
            return None
        return (time_s if self.clock is None else self.clock.time(time_s, seq), motor_deg, load_deg, seq, after_gap)

    def _corrupt(self, reason: str, n_frames: int) -> None:
        if self.strict:
            raise FrameError(reason)
        self.counters.corrupt += n_frames

"""The last checks before a Sample leaves any source: finite values, time order, gaps.

Shared by the CAN pipeline and the serial parsers so that every adapter applies the same rules:
a non-finite value or a time that goes backwards makes the frame(s) corrupt (never yielded), and
a gap (counter jump, or a step longer than three nominal periods) is counted with its time and
length and flagged on the next sample (``after_gap=True``).
"""

from __future__ import annotations

import math

from online_backlash.errors import FrameError
from online_backlash.stream import Sample, StreamCounters

from .gaps import GapDetector


class SampleAssembler:
    """Turn checked readings into Samples, counting into ``counters``.

    Parameters
    ----------
    counters : StreamCounters
        Updated in place (``samples``, ``corrupt``, ``gaps``).
    counter_modulus : int or None
        Wrap of the source's sequence counter (None: gaps from time steps only).
    period_s : float or None
        Nominal sample period, seconds (None: learnt).
    strict : bool
        Raise FrameError instead of counting a bad reading as corrupt.
    """

    def __init__(self, counters: StreamCounters, counter_modulus: int | None, period_s: float | None, strict: bool) -> None:
        self.counters = counters
        self.strict = strict
        self.gaps = GapDetector(counter_modulus, period_s)
        self._last_time = -math.inf

    def make(self, time_s: float, motor_deg: float, load_deg: float, seq: int | None, n_frames: int = 1) -> Sample | None:
        """The Sample of these readings (degrees, seconds), or None if it is corrupt (``n_frames`` counted)."""
        if not (math.isfinite(time_s) and math.isfinite(motor_deg) and math.isfinite(load_deg)):
            return self._corrupt("non-finite value", n_frames)
        if time_s < self._last_time:
            return self._corrupt(f"time goes backwards ({time_s!r} s after {self._last_time!r} s)", n_frames)
        self._last_time = time_s
        gap = self.gaps.check(time_s, seq)
        if gap is not None:
            self.counters.report_gap(gap)
        self.counters.samples += 1
        return Sample(time_s, motor_deg, load_deg, None, seq, gap is not None)

    def _corrupt(self, reason: str, n_frames: int) -> None:
        if self.strict:
            raise FrameError(reason)
        self.counters.corrupt += n_frames
        return None

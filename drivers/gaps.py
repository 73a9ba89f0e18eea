"""Gap detection shared by the live adapters and the log readers.

A gap is reported when a rolling counter skips values, or when a time step is longer than
:data:`~online_backlash.stream.GAP_PERIODS` nominal periods (the rule of every source).
The nominal period is given, or learnt as the median of the first steps without a counter jump.
"""

from __future__ import annotations

import statistics

from online_backlash.errors import InvalidParameterError
from online_backlash.stream import GAP_PERIODS, Gap


class GapDetector:
    """Decide, sample by sample, whether samples are missing before this one.

    Parameters
    ----------
    counter_modulus : int or None
        The rolling counter wraps at this value (16 for a 4-bit counter); None when the
        source has no counter (gaps are then found from time steps only).
    period_s : float or None
        Nominal sample period, seconds; None to learn it from the first ``learn_steps`` steps.
    learn_steps : int
        Steps used to learn the period.
    """

    def __init__(self, counter_modulus: int | None = None, period_s: float | None = None, learn_steps: int = 16) -> None:
        if counter_modulus is not None and counter_modulus < 2:
            raise InvalidParameterError(f"counter_modulus must be >= 2 or None, got {counter_modulus!r}")
        if period_s is not None and not period_s > 0:
            raise InvalidParameterError(f"period_s must be positive or None, got {period_s!r}")
        self.counter_modulus = counter_modulus
        self.period_s = period_s
        self.learn_steps = int(learn_steps)
        self._steps: list[float] = []
        self._last_time: float | None = None
        self._last_counter: int | None = None

    def check(self, time_s: float, counter: int | None = None) -> Gap | None:
        """Register the next sample; return the gap before it, if any."""
        last_time, last_counter = self._last_time, self._last_counter
        self._last_time, self._last_counter = time_s, counter
        if last_time is None:
            return None
        dt = time_s - last_time
        missing = 0
        if self.counter_modulus is not None and counter is not None and last_counter is not None:
            missing = (counter - last_counter - 1) % self.counter_modulus
        if self.period_s is None:
            if missing == 0:
                self._steps.append(dt)
                if len(self._steps) == self.learn_steps:
                    median = statistics.median(self._steps)
                    self.period_s = median if median > 0 else None
                    self._steps.clear()
            return Gap(time_s, dt, missing) if missing else None
        if missing or dt > GAP_PERIODS * self.period_s:
            return Gap(time_s, dt, max(missing, int(round(dt / self.period_s)) - 1))
        return None

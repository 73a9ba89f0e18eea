"""Gap detection: the one rule of every source (CAN and serial frames, live and replayed, and CSV rows).

A gap is reported when a rolling counter skips values, or when a time step is longer than
:data:`~online_backlash.stream.GAP_PERIODS` nominal periods (:func:`step_is_gap`; the samples
missing in it: :func:`missing_in_step`). The nominal period is given, or learnt from the first
``learn_steps`` steps without a counter jump (their median; with a counter, their mean, which host
timestamps bunched in bursts do not bias); until it is known, only counter jumps are gaps.

Bursts are not gaps: a host-timestamped adapter delivers frames in bunches of 1-5 ms, so the
timestamps stall and then leap while the counter runs on. Where the counter is continuous, a time
step is a gap only when it is longer than :func:`gap_periods` nominal periods: half the counter's
cycle, and never fewer than ``GAP_PERIODS`` (a loss of a whole cycle of frames, which the counter
cannot show, still shows in the time). :class:`GapDetector` applies the rule sample by sample
(:meth:`GapDetector.check`) or to a
block of timestamps without counters (:meth:`GapDetector.check_times`, CSV rows; tested equal).
The compiled pairing loop of CAN replay (:mod:`~online_backlash.codecs.blockpairing`) applies the
same rule inside numba and is held equal to the per-frame path by ``tests/test_can_blocks.py``.

Time from the counter: where the nominal period is given and the source has a rolling counter,
:class:`CounterClock` gives each sample the time ``t0 + n * period`` (``n`` the unwrapped counter),
so jittery timestamps do not reach the estimator or the data clock.
"""

from __future__ import annotations

import math
import statistics

import numpy as np
from numba import njit

from online_backlash.errors import InvalidParameterError
from online_backlash.stream import GAP_PERIODS, Gap


def step_is_gap(dt: float | np.ndarray, period_s: float, periods: float = GAP_PERIODS) -> bool | np.ndarray:
    """True where a time step ``dt`` (seconds) is longer than ``periods`` nominal periods (default ``GAP_PERIODS``)."""
    return dt > periods * period_s


def gap_periods(counter_modulus: int | None) -> float:
    """Nominal periods a time step must exceed to be a gap: ``GAP_PERIODS`` without a counter; with a
    counter wrapping at ``counter_modulus``, half its cycle plus one (at least ``GAP_PERIODS``), so
    that bursts of bunched timestamps are not gaps while a lost whole cycle still is.

    >>> gap_periods(None), gap_periods(4), gap_periods(16)
    (3.0, 3.0, 8.5)
    """
    return GAP_PERIODS if counter_modulus is None else max(GAP_PERIODS, (counter_modulus + 1) / 2)


def missing_in_step(dt: float, period_s: float) -> int:
    """Samples missing in a step of ``dt`` seconds at a nominal period of ``period_s`` (rounded half to even)."""
    return round(dt / period_s) - 1


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

    Examples
    --------
    >>> gaps = GapDetector(period_s=0.001)
    >>> [gaps.check(t) for t in (0.0, 0.001, 0.002)]
    [None, None, None]
    >>> gaps.check(0.010)
    Gap(time_s=0.01, duration_s=0.008, missing=7)
    """

    def __init__(
        self, counter_modulus: int | None = None, period_s: float | None = None, learn_steps: int = 16
    ) -> None:
        if counter_modulus is not None and counter_modulus < 2:
            raise InvalidParameterError(f"counter_modulus must be >= 2 or None, got {counter_modulus!r}")
        if period_s is not None and not period_s > 0:
            raise InvalidParameterError(f"period_s must be positive or None, got {period_s!r}")
        self.counter_modulus = counter_modulus
        self.period_s = period_s
        self.gap_periods = gap_periods(counter_modulus)
        self.learn_steps = int(learn_steps)
        self._steps: list[float] = []
        self._last_time: float | None = None
        self._last_counter: int | None = None

    def check(self, time_s: float, counter: int | None = None) -> Gap | None:
        """Register the next sample (time in seconds); return the gap before it, if any."""
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
                self._learn([dt])
            return Gap(time_s, dt, missing) if missing else None
        if missing or step_is_gap(dt, self.period_s, self.gap_periods):
            return Gap(time_s, dt, max(missing, missing_in_step(dt, self.period_s)))
        return None

    def check_times(self, time_s: np.ndarray) -> tuple[np.ndarray, list[Gap]]:
        """:meth:`check` for a block of timestamps (seconds) without counters.

        Returns ``after_gap`` (True where a gap precedes the sample) and the gaps, in order. The
        steps after the period is known are tested in one compiled pass (:func:`_flag_gaps`,
        ``nogil``), the same rule as :meth:`check` (tested equal).
        """
        time_s = np.asarray(time_s, dtype=float)
        n = time_s.shape[0]
        after_gap = np.zeros(n, dtype=bool)
        if n == 0:
            return after_gap, []
        first = 0 if self._last_time is not None else 1
        last = self._last_time if self._last_time is not None else math.nan
        self._last_time, self._last_counter = float(time_s[-1]), None
        while self.period_s is None and first < n:
            take = min(self.learn_steps - len(self._steps), n - first)
            before = time_s[first - 1] if first > 0 else last
            self._learn(np.diff(time_s[first : first + take], prepend=before).tolist())
            first += take
        if self.period_s is None or first >= n:
            return after_gap, []
        period = self.period_s
        start = time_s[first - 1] if first > 0 else last
        if not _flag_gaps(time_s, first, start, period * self.gap_periods, after_gap):
            return after_gap, []
        index = np.flatnonzero(after_gap)
        steps = time_s[index] - np.where(index > 0, time_s[index - 1], start)
        return after_gap, [
            Gap(t, d, missing_in_step(d, period)) for t, d in zip(time_s[index].tolist(), steps.tolist())
        ]

    def _learn(self, steps: list[float]) -> None:
        """Take steps (seconds) towards the learnt period: the median of the first ``learn_steps``, or with a
        counter their mean (again if not positive)."""
        self._steps.extend(steps)
        if len(self._steps) == self.learn_steps:
            period = statistics.median(self._steps) if self.counter_modulus is None else statistics.fmean(self._steps)
            self.period_s = period if period > 0 else None
            self._steps.clear()


@njit(cache=True, nogil=True)
def _flag_gaps(
    time_s: np.ndarray, first: int, before: float, longest_s: float, after_gap: np.ndarray
) -> int:  # pragma: no cover - compiled
    """Set ``after_gap[i]`` for ``i >= first`` where the step to ``time_s[i]`` (from ``time_s[i - 1]``, or
    ``before`` for ``i == 0``) is longer than ``longest_s`` seconds (:func:`step_is_gap`); returns how many."""
    found = 0
    previous = before
    for i in range(first, time_s.shape[0]):
        if i > 0:
            previous = time_s[i - 1]
        if time_s[i] - previous > longest_s:
            after_gap[i] = True
            found += 1
    return found


class CounterClock:
    """Sample times from the frame counter and the nominal period, where the timestamps are jittery.

    Host-timestamped adapters deliver frames in bursts of 1-5 ms, so the frame timestamps stall and
    leap while the source's rolling counter runs on. Given the nominal period (``--period``), the
    time of a sample is ``t0 + n * period_s``: ``t0`` the timestamp of the first sample and ``n`` the
    unwrapped counter, the periods counted since it. Between consecutive samples the counter
    advances by ``k = (seq - last_seq) mod counter_modulus``; the timestamps decide only how many
    whole counter cycles were lost besides (``n_step = k + modulus * max(0, round((dt / period_s - k) / modulus))``
    with ``dt`` the timestamp step: jitter below half a cycle changes nothing). A sample without a
    counter value steps ``max(0, round(dt / period_s))`` periods. The time then no longer depends
    on when the frames arrived, so a live run and the replay of its log give the same times; the
    gap rule (:class:`GapDetector`) still reads the timestamps.

    :meth:`time` takes samples one by one (live, per frame), :meth:`times` a block (replay); they
    give the same times, whatever the blocks (``n`` is an integer, ``t0 + n * period_s`` one
    rounding).

    Parameters
    ----------
    counter_modulus : int
        The counter wraps at this value (16 for a 4-bit counter).
    period_s : float
        Nominal sample period, seconds.

    Examples
    --------
    >>> clock = CounterClock(16, 0.001)
    >>> [round(clock.time(t, q), 6) for t, q in ((10.0, 5), (10.0, 6), (10.0, 7), (10.004, 8), (10.0041, 10))]
    [10.0, 10.001, 10.002, 10.003, 10.005]
    """

    def __init__(self, counter_modulus: int, period_s: float) -> None:
        if counter_modulus < 2:
            raise InvalidParameterError(f"counter_modulus must be >= 2, got {counter_modulus!r}")
        if not period_s > 0:
            raise InvalidParameterError(f"period_s must be positive, got {period_s!r}")
        self.counter_modulus = int(counter_modulus)
        self.period_s = float(period_s)
        self._t0: float | None = None
        self._n = 0
        self._last_time = 0.0
        self._last_seq = -1

    def time(self, time_s: float, seq: int | None) -> float:
        """The time (s) of the next sample, timestamped ``time_s`` (s) with counter value ``seq`` (None or < 0:
        none)."""
        q = -1 if seq is None else int(seq)
        if self._t0 is None:
            self._t0 = float(time_s)
        else:
            periods = (time_s - self._last_time) / self.period_s
            if q < 0 or self._last_seq < 0:
                self._n += max(0, round(periods))
            else:
                k = (q - self._last_seq) % self.counter_modulus
                self._n += k + self.counter_modulus * max(0, round((periods - k) / self.counter_modulus))
        self._last_time, self._last_seq = float(time_s), q
        return self._t0 + self._n * self.period_s

    def times(self, time_s: np.ndarray, seq: np.ndarray | None) -> np.ndarray:
        """:meth:`time` of a block of samples: timestamps (s) and counter values (-1 or None: none)."""
        size = time_s.shape[0]
        if size == 0:
            return np.asarray(time_s, dtype=float).copy()
        q = np.full(size, -1, dtype=np.int64) if seq is None else np.asarray(seq, dtype=np.int64)
        first = 0
        if self._t0 is None:
            self._t0 = float(time_s[0])
            first = 1
        prev_time = np.concatenate(([self._last_time], time_s[:-1]))[first:]
        prev_seq = np.concatenate(([self._last_seq], q[:-1]))[first:]
        periods = (time_s[first:] - prev_time) / self.period_s
        modulus = self.counter_modulus
        k = (q[first:] - prev_seq) % modulus
        whole = np.maximum(0.0, np.round((periods - k) / modulus)).astype(np.int64)
        plain = np.maximum(0.0, np.round(periods)).astype(np.int64)
        steps = np.where((q[first:] < 0) | (prev_seq < 0), plain, k + modulus * whole)
        n = np.empty(size, dtype=np.int64)
        n[:first] = self._n
        n[first:] = self._n + np.cumsum(steps)
        self._n = int(n[-1])
        self._last_time, self._last_seq = float(time_s[-1]), int(q[-1])
        return self._t0 + n * self.period_s

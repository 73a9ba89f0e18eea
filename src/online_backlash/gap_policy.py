"""What a gap does to a recursive estimator, stated once: :class:`GapPolicy` and :class:`GapTally`.

A source flags a gap (``after_gap``: samples are missing just before this one; the frame rule of
:mod:`online_backlash.codecs.gaps`). The estimator (:class:`~online_backlash.estimators.RecursiveEstimator`,
``gap_policy``) decides with :meth:`GapPolicy.split` whether it is *bridged* (a short gap without a
jump: the state is kept and the sample after the gap is learned from the one before it) or
*restarts* its reading of the motion; :class:`GapTally` counts them (the estimator's ``gaps_``,
the gap figures of every result, :data:`~online_backlash.output_columns.GAP_KEYS`).

Units: seconds, degrees (referred to the load side).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InvalidParameterError
from .output_columns import GAP_KEYS
from .stream import SampleChunk

#: Default longest gap bridged, seconds: 100 nominal periods of a 1 kHz log (a lost frame, a USB
#: adapter's stall); a longer gap restarts the estimator's reading of the motion.
BRIDGE_S = 0.1
#: Default largest step of either angle across a bridged gap, degrees on the load side: more than
#: a shaft travels in BRIDGE_S at rig speeds (tens of deg/s), so a larger step is a jump in the data
#: (an encoder re-zeroed, another log) and restarts.
JUMP_DEG = 5.0

#: The last sample before a block when nothing is known of it (a new stream, after ``mark_gap``).
UNKNOWN = (math.nan, math.nan, math.nan)


def steps_across(index: np.ndarray, x: np.ndarray, before: float) -> np.ndarray:
    """``x[i] - x[i - 1]`` at each ``i`` of ``index`` (sorted), with ``before`` standing for ``x[-1]``."""
    previous = x[np.maximum(index - 1, 0)]
    if index.size and index[0] == 0:
        previous = previous.copy()
        previous[0] = before
    return x[index] - previous


@dataclass(frozen=True)
class GapPolicy:
    """Which gaps the estimator is carried across (*bridged*) and which restart its reading of the motion.

    A gap (``after_gap`` of a sample) is *short* when the time step across it is at most
    ``bridge_s`` seconds (and positive), and a *jump* when the referred motor angle ``u`` or the
    load angle ``y`` changes by more than ``jump_deg`` degrees across it. A short gap without a
    jump is bridged: the estimator keeps its state (warm-up buffer, flank, covariance) and learns
    the sample after the gap from the one before it, as one longer step. A long gap, a jump, a
    gap whose duration is unknown (no ``time_s`` given) or the first sample after ``mark_gap()``
    restarts. ``bridge_s=0`` bridges nothing (every gap restarts, the behaviour before bridging).
    """

    bridge_s: float = BRIDGE_S
    jump_deg: float = JUMP_DEG

    def __post_init__(self) -> None:
        for name in ("bridge_s", "jump_deg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise InvalidParameterError(f"{name} must be a finite number >= 0, got {value!r}")

    def bridged(self, dt_s: np.ndarray, du_deg: np.ndarray, dy_deg: np.ndarray) -> np.ndarray:
        """True where a gap with time step ``dt_s`` (s) and angle steps ``du_deg``, ``dy_deg`` (deg) is bridged
        (NaN steps, i.e. no sample before the gap, are never bridged)."""
        with np.errstate(invalid="ignore"):
            return (
                (dt_s > 0.0)
                & (dt_s <= self.bridge_s)
                & (np.abs(du_deg) <= self.jump_deg)
                & (np.abs(dy_deg) <= self.jump_deg)
            )

    def split(
        self,
        after_gap: np.ndarray,
        time_s: np.ndarray | None,
        u: np.ndarray,
        y: np.ndarray,
        last: tuple[float, float, float],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Decide the gaps of one block: ``(restarts, dt_s, bridged)``.

        ``restarts`` is ``after_gap`` without the gaps bridged; ``dt_s`` (s, NaN where unknown)
        and ``bridged`` give one value per flagged gap, for :meth:`GapTally.add`. ``last`` is the
        ``(time_s, u, y)`` of the sample before the block (:data:`UNKNOWN` if none); without
        ``time_s`` no gap is bridged (its duration is unknown).
        """
        index = np.flatnonzero(after_gap)
        t = np.full(u.size, math.nan) if time_s is None else time_s
        dt, du, dy = (steps_across(index, x, x0) for x, x0 in zip((t, u, y), last))
        bridged = self.bridged(dt, du, dy)
        restarts = after_gap
        if bridged.any():
            restarts = after_gap.copy()
            restarts[index[bridged]] = False
        return restarts, dt, bridged

    def as_dict(self) -> dict[str, float]:
        """The settings as JSON values (a saved estimator's parameters)."""
        return {"bridge_s": float(self.bridge_s), "jump_deg": float(self.jump_deg)}


@dataclass
class GapTally:
    """The gaps a stream had: count, longest and total time step across them (seconds), and how many were bridged."""

    gaps: int = 0
    longest_s: float = 0.0
    total_s: float = 0.0
    bridged: int = 0

    def add(self, dt_s: np.ndarray, bridged: np.ndarray) -> None:
        """Count gaps with time steps ``dt_s`` (s; NaN where the step is unknown) and their bridged flags."""
        known = dt_s[np.isfinite(dt_s)]
        self.gaps += int(dt_s.size)
        self.bridged += int(np.count_nonzero(bridged))
        if known.size:
            self.longest_s = max(self.longest_s, float(known.max()))
            self.total_s += float(known.sum())

    def values(self) -> dict[str, float | int]:
        """The gap figures of a result (:data:`~online_backlash.output_columns.GAP_KEYS`)."""
        return dict(zip(GAP_KEYS, (self.longest_s, self.total_s, self.bridged)))

    @classmethod
    def of_chunk(cls, chunk: SampleChunk) -> GapTally:
        """The gaps of one whole log in memory (no gap bridged: a batch fit reads no motion across them)."""
        tally = cls()
        index = np.flatnonzero(chunk.after_gap[1:]) + 1
        tally.add(chunk.time_s[index] - chunk.time_s[index - 1], np.zeros(index.size, dtype=bool))
        if chunk.after_gap.size and chunk.after_gap[0]:
            tally.add(np.array([np.nan]), np.zeros(1, dtype=bool))
        return tally

"""How much a gearbox has been used: operating hours, load revolutions and reversals since new.

All three are read from the motor angle referred to the load side, ``u = motor_deg / ratio``
(degrees): the motor encoder is fine and does not see the play, while the load encoder's
noise would add up to spurious travel. A hysteresis of ``reversal_deg`` keeps encoder jitter
from counting:

* the counter follows the furthest point ``anchor`` reached in the current direction; ``u``
  going beyond it is travel (``load_revolutions`` += distance / 360);
* ``u`` coming back from the anchor by more than ``reversal_deg`` is a reversal: the distance
  back is travel too, and the anchor and direction flip;
* a step counts as operating time when the shaft made progress (new travel or a reversal)
  within the last ``idle_after_s`` seconds; time spent standing still is not counted.

Steps across a gap (``after_gap``) or from one log to the next (:meth:`UsageCounter.mark_gap`)
add neither time nor travel. The counter's state is a few numbers, saved in the history
store's checkpoint with the estimator's, so counts continue across logs and restarts.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..errors import InvalidParameterError

# state vector layout (float64 so that one array carries it through numba)
_HAS_PREV, _PREV_T, _ANCHOR, _DIRECTION, _LAST_PROGRESS_T, _OPERATING_S, _TRAVEL_DEG, _REVERSALS = range(8)
_STATE_NAMES = (
    "has_prev",
    "prev_time_s",
    "anchor_deg",
    "direction",
    "last_progress_s",
    "operating_s",
    "travel_deg",
    "reversals",
)


@njit(cache=True)
def _count(state, time_s, u_deg, after_gap, reversal_deg, idle_after_s):  # pragma: no cover - compiled
    has_prev, prev_t = state[_HAS_PREV], state[_PREV_T]
    anchor, direction, last_progress = state[_ANCHOR], state[_DIRECTION], state[_LAST_PROGRESS_T]
    operating, travel, reversals = state[_OPERATING_S], state[_TRAVEL_DEG], state[_REVERSALS]
    for i in range(time_s.size):
        t, u = time_s[i], u_deg[i]
        if has_prev == 0.0 or after_gap[i]:
            # a new segment: no step to count; anchor here, direction unknown, not moving yet
            anchor, direction, last_progress = u, 0.0, -np.inf
        else:
            progress = False
            if direction == 0.0:
                if abs(u - anchor) > reversal_deg:
                    direction = 1.0 if u > anchor else -1.0
                    travel += abs(u - anchor)
                    anchor, progress = u, True
            elif (u - anchor) * direction > 0.0:
                travel += abs(u - anchor)
                anchor, progress = u, True
            elif abs(u - anchor) > reversal_deg:
                travel += abs(u - anchor)
                anchor, direction, progress = u, -direction, True
                reversals += 1.0
            if progress:
                last_progress = t
            if t - last_progress <= idle_after_s:
                operating += t - prev_t
        has_prev, prev_t = 1.0, t
    state[_HAS_PREV], state[_PREV_T] = has_prev, prev_t
    state[_ANCHOR], state[_DIRECTION], state[_LAST_PROGRESS_T] = anchor, direction, last_progress
    state[_OPERATING_S], state[_TRAVEL_DEG], state[_REVERSALS] = operating, travel, reversals


class UsageCounter:
    """Operating time, load revolutions and reversals of a stream of load-side angles.

    Parameters
    ----------
    reversal_deg : float
        Hysteresis, degrees (load side): a move back by more than this is a reversal; jitter
        below it is ignored.
    idle_after_s : float
        Seconds without progress after which the shaft counts as standing still.

    Attributes
    ----------
    operating_hours : float
        Time in motion, hours.
    load_revolutions : float
        Distance travelled by the load shaft in either direction, revolutions.
    reversals : int
        Changes of direction.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(0, 4.0, 0.001)
    >>> u = np.where(t < 2.0, 90.0 * t, 360.0 - 90.0 * t)   # 180 deg out, 180 deg back
    >>> c = UsageCounter()
    >>> c.update(t, u)
    >>> round(c.load_revolutions, 3), c.reversals, round(c.operating_hours * 3600, 2)
    (1.0, 1, 4.0)
    """

    def __init__(self, reversal_deg: float = 0.05, idle_after_s: float = 0.5) -> None:
        self.reversal_deg = reversal_deg
        self.idle_after_s = idle_after_s
        self._state = np.zeros(len(_STATE_NAMES))
        self._state[_LAST_PROGRESS_T] = -np.inf

    def update(self, time_s: np.ndarray, u_deg: np.ndarray, after_gap: np.ndarray | None = None) -> None:
        """Count a block of samples: times (s), load-side angles (deg), gap flags."""
        for name in ("reversal_deg", "idle_after_s"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not value > 0
                or not np.isfinite(value)
            ):
                raise InvalidParameterError(f"{name} must be a finite real number > 0, got {value!r}")
        time_s = np.ascontiguousarray(time_s, dtype=float)
        u_deg = np.ascontiguousarray(u_deg, dtype=float)
        gaps = np.zeros(time_s.size, dtype=bool) if after_gap is None else np.ascontiguousarray(after_gap, dtype=bool)
        if not (time_s.shape == u_deg.shape == gaps.shape) or time_s.ndim != 1:
            raise InvalidParameterError(
                f"time_s, u_deg and after_gap must be 1-D of equal length, got {time_s.shape}, {u_deg.shape}, "
                f"{gaps.shape}"
            )
        _count(self._state, time_s, u_deg, gaps, float(self.reversal_deg), float(self.idle_after_s))

    def mark_gap(self) -> None:
        """The next sample does not follow the last one (a new log, a dropped connection)."""
        self._state[_HAS_PREV] = 0.0

    @property
    def operating_hours(self) -> float:
        return float(self._state[_OPERATING_S]) / 3600.0

    @property
    def load_revolutions(self) -> float:
        return float(self._state[_TRAVEL_DEG]) / 360.0

    @property
    def reversals(self) -> int:
        return int(self._state[_REVERSALS])

    def state_dict(self) -> dict:
        """Parameters and counts as a JSON-serialisable dict (``-inf`` is written as None)."""
        values = [None if not np.isfinite(v) else float(v) for v in self._state]
        return {
            "reversal_deg": self.reversal_deg,
            "idle_after_s": self.idle_after_s,
            "state": dict(zip(_STATE_NAMES, values)),
        }

    @classmethod
    def from_state(cls, d: dict) -> UsageCounter:
        """Rebuild a counter saved by :meth:`state_dict`."""
        counter = cls(d["reversal_deg"], d["idle_after_s"])
        counter._state = np.array(
            [-np.inf if d["state"][k] is None else d["state"][k] for k in _STATE_NAMES], dtype=float
        )
        return counter

"""The load condition behind each stored estimate: mean and RMS of the transmitted torque.

A play measured under a preload (the torque never reverses) or at another torque level is not
the same measurement as one taken with the torque swinging through zero (issue 12): the store
keeps, with every estimate, the torque the data behind it carried, so that estimates can be
compared like with like. :class:`LoadCondition` sums the finite torque samples since the last
estimate; :meth:`LoadCondition.take` gives their mean and RMS (N m; None without torque) and
starts the next window; :meth:`LoadCondition.reversed_since_last` tells whether the torque
reversed within the window (a window without a reversal carries no information on the
play). Its state (four numbers) rides in the tracker's checkpoint, so a resumed
run continues the window.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["LoadCondition"]


class LoadCondition:
    """Mean and RMS of the transmitted torque over the samples since the last estimate (N m)."""

    def __init__(self, count: int = 0, total_nm: float = 0.0, total_sq_nm2: float = 0.0, reversals: int = 0) -> None:
        self.count = int(count)
        self.total_nm = float(total_nm)
        self.total_sq_nm2 = float(total_sq_nm2)
        self.reversals = int(reversals)

    def reversed_since_last(self, reversals: int) -> bool:
        """True when the estimator's count of (torque) reversals grew since the last call: the data
        behind this estimate showed both flanks. Remembers ``reversals`` for the next call."""
        grew = int(reversals) > self.reversals
        self.reversals = int(reversals)
        return grew

    def update(self, torque_Nm: np.ndarray | None) -> None:
        """Add a block's torque (N m; NaN where the source has none, which is skipped)."""
        if torque_Nm is None:
            return
        q = np.asarray(torque_Nm, dtype=float)
        q = q[np.isfinite(q)]
        if q.size:
            self.count += int(q.size)
            self.total_nm += float(q.sum())
            self.total_sq_nm2 += float(np.dot(q, q))

    def take(self) -> dict[str, float | None]:
        """``torque_mean_nm`` and ``torque_rms_nm`` of the window (None without torque), and a new window."""
        if self.count:
            values: dict[str, float | None] = {
                "torque_mean_nm": self.total_nm / self.count,
                "torque_rms_nm": math.sqrt(max(self.total_sq_nm2, 0.0) / self.count),
            }
        else:
            values = {"torque_mean_nm": None, "torque_rms_nm": None}
        self.count, self.total_nm, self.total_sq_nm2 = 0, 0.0, 0.0
        return values

    def state_dict(self) -> dict[str, Any]:
        """The window so far, JSON-serialisable."""
        return {
            "count": self.count,
            "total_nm": self.total_nm,
            "total_sq_nm2": self.total_sq_nm2,
            "reversals": self.reversals,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any] | None) -> LoadCondition:
        """The window of :meth:`state_dict` (a checkpoint written before it had one: an empty window)."""
        return cls(**state) if state else cls()

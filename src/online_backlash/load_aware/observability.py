"""Is the play observable without a torque signal? The load must hold still while the motor crosses the gap.

Without torque the only evidence of the play is kinematic: after the motor reverses, the load
stays where it was while the motor travels through the gap, then follows (eq. 1-3's held
output). If the load never holds still at a reversal -- held against one flank by an external
torque, it follows the motor at once -- the data say nothing about the play, however well a
model fits them. :class:`DwellTracker` measures, at every reversal of the input, the *dwell*:
the input's travel from its turning point until the output has moved by more than its own noise
band. A dwell larger than :data:`DWELL_FACTOR` noise bands shows the gap; the largest dwell is
a lower bound of the play (the load held still over that much motor travel).

Streaming (one small state, arrays in, compiled), so it runs beside a recursive estimator.
Units: degrees (load side).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..errors import InvalidParameterError
from .engagement import torque_noise_std

__all__ = ["DWELL_FACTOR", "DwellTracker", "still_band"]

#: A dwell counts as showing the gap when it exceeds this many output noise bands.
DWELL_FACTOR = 4.0

# state: 0 direction (+1/-1, 0 unknown), 1 u extreme, 2 y at the extreme, 3 dwelling (1/0),
# 4 reversals, 5 largest dwell, 6 reversals with a dwell above the threshold, 7 have a sample,
# 8 u at the turning point, 9 y at the turning point
_N_STATE = 10


@njit(cache=True, nogil=True)
def _dwell_run(st, u, y, gap, h_u, h_y, threshold):  # pragma: no cover - compiled
    """The dwell search over a block (the state ``st`` as laid out above, kept in locals in the loop)."""
    d, u_ext, y_ext, dwelling, n_rev, max_dwell, n_gap, have, u_turn, y_turn = (
        st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9]
    )  # fmt: skip
    for i in range(u.shape[0]):
        ui, yi = u[i], y[i]
        if gap[i] or have == 0.0:  # (re)start: no direction, no dwell
            d, u_ext, y_ext, dwelling, have = 0.0, ui, yi, 0.0, 1.0
            continue
        if d == 0.0:
            if abs(ui - u_ext) > h_u:
                d = 1.0 if ui > u_ext else -1.0
                u_ext, y_ext = ui, yi
            continue
        if (ui - u_ext) * d >= 0.0:  # on in the same direction: the extreme moves
            u_ext, y_ext = ui, yi
        elif abs(ui - u_ext) > h_u:  # turned back beyond the noise band: a reversal at the extreme
            n_rev += 1.0
            dwelling = 1.0
            u_turn, y_turn = u_ext, y_ext
            d = -d
            u_ext, y_ext = ui, yi
        if dwelling != 0.0:
            travel = abs(ui - u_turn)
            if travel > max_dwell:
                max_dwell = travel
            if abs(yi - y_turn) > h_y:  # the load moved: the dwell ends
                if travel > threshold:
                    n_gap += 1.0
                dwelling = 0.0
    st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9] = (
        d, u_ext, y_ext, dwelling, n_rev, max_dwell, n_gap, have, u_turn, y_turn
    )  # fmt: skip


def still_band(x_deg: np.ndarray) -> float:
    """The band (deg) within which a signal counts as still: 4 robust noise standard deviations of
    its second difference, at least 1.5 quantisation steps (its smallest non-zero step)."""
    x = np.asarray(x_deg, dtype=float)
    if x.size < 3:
        raise InvalidParameterError(f"need at least 3 samples to tell noise from motion, got {x.size}")
    steps = np.abs(np.diff(x))
    steps = steps[steps > 0]
    quantum = float(steps.min()) if steps.size else 0.0
    return max(4.0 * torque_noise_std(x), 1.5 * quantum, 1e-9)


class DwellTracker:
    """Reversals of the input and the output's dwell after each (module docstring).

    The noise bands of input and output are taken from the first block given (:func:`still_band`)
    unless ``band_u_deg`` / ``band_y_deg`` are set.

    Attributes
    ----------
    reversals_ : int
        Reversals of the input (through its noise band).
    dwells_showing_gap_ : int
        Reversals after which the load held still over more than ``DWELL_FACTOR`` output bands.
    max_dwell_deg_ : float
        The largest input travel with the load still, degrees: a lower bound of the play.
    """

    def __init__(self, band_u_deg: float | None = None, band_y_deg: float | None = None) -> None:
        self.band_u_deg = band_u_deg
        self.band_y_deg = band_y_deg
        self._st = np.zeros(_N_STATE)

    def update(self, u_deg: np.ndarray, y_deg: np.ndarray, after_gap: np.ndarray | None = None) -> None:
        """Learn consecutive samples (input and output, degrees; ``after_gap`` restarts the search)."""
        u = np.ascontiguousarray(u_deg, dtype=float)
        y = np.ascontiguousarray(y_deg, dtype=float)
        if u.size == 0:
            return
        if self.band_u_deg is None and u.size >= 3:
            self.band_u_deg = still_band(u)
        if self.band_y_deg is None and y.size >= 3:
            self.band_y_deg = still_band(y)
        if self.band_u_deg is None or self.band_y_deg is None:
            return  # fewer than 3 samples in the first block: wait for more
        gap = np.zeros(u.size, dtype=bool) if after_gap is None else np.ascontiguousarray(after_gap, dtype=bool)
        _dwell_run(self._st, u, y, gap, self.band_u_deg, self.band_y_deg, self.threshold_deg)

    @property
    def threshold_deg(self) -> float:
        """The dwell that shows the gap, degrees (NaN before the bands are known)."""
        return math.nan if self.band_y_deg is None else DWELL_FACTOR * self.band_y_deg

    @property
    def reversals_(self) -> int:
        return int(self._st[4])

    @property
    def dwells_showing_gap_(self) -> int:
        return int(self._st[6])

    @property
    def max_dwell_deg_(self) -> float:
        return float(self._st[5])

    @property
    def observable_(self) -> bool:
        """At least one reversal showed the gap (the load held still while the motor crossed it)."""
        return self.dwells_showing_gap_ >= 1

"""Is the play observable without a torque signal? The load must hold still while the motor crosses the gap.

Without torque the only evidence of the play is kinematic: after the motor reverses, the load
stays where it was while the motor travels through the gap, then follows (eq. 1-3's held
output). If the load never holds still at a reversal -- held against one flank by an external
torque, it follows the motor at once -- the data say nothing about the play, however well a
model fits them. :class:`DwellTracker` measures, at every reversal of the input, the *dwell*:
the input's travel from its turning point until the output follows it, i.e. has moved by more than
its own noise band in the input's new direction (a load that coasts or creeps on the old way is
not following: the flanks are still open, and the dwell goes on from where it got to). A dwell
larger than :data:`DWELL_FACTOR` noise bands shows the gap; the largest dwell, less the two noise
bands within which neither end of it can be placed, is a lower bound of the play (the load did not
follow over that much motor travel).

Each dwell that shows the gap is kept as a :class:`Dwell` with the torque at its two ends and in
its middle, where a torque column is given: the evidence a torque-sign model is tested against
(issue 27, :mod:`.choice`). A dwell begins with the old flank unwinding and ends with the new one
winding up until the load moves; in its middle half (by the motor's travel) the motor crosses the
gap and no flank touches, so what the sensor reads there is what it reads when the flank the motor
moves towards begins to carry (:func:`engagement_torques`); and a model of the flanks must predict
the motor travel of every dwell from the torques at its two ends.

The first :data:`PREFIX_SAMPLES` samples give the noise bands and each encoder's *resolution* (its
quantum and its noise, from the gaps between its values and its second differences; the same samples
however the stream is cut into blocks, so nothing here depends on the cutting):
:attr:`DwellTracker.quantisation_deg` and :attr:`DwellTracker.sample_resolution_deg`, what
:func:`online_backlash.physical.play_verdict` compares a play and its standard error with.

Streaming (one small state, arrays in, compiled), so it runs beside a recursive estimator; its
state is plain JSON (:meth:`DwellTracker.state_dict`) for a checkpoint.
Units: degrees (load side), N m.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from ..estimators.resolution import DWELL_FACTOR, quantum_and_noise, still_band

__all__ = [
    "DWELL_FACTOR",
    "MAX_DWELLS",
    "Dwell",
    "DwellTracker",
    "engagement_torques",
    "quantum_and_noise",
    "still_band",
]

#: Dwells kept (the latest): enough for their medians, bounded over weeks of tracking.
MAX_DWELLS = 200
#: Samples at the start of a stream that give the noise bands and the encoders' resolution (10 s at 1 kHz): the
#: same samples however the stream is cut into blocks.
PREFIX_SAMPLES = 10_000

#: Samples of the current dwell kept for the torque in its middle (the latest, where it is longer).
DWELL_SAMPLES = 2048

# state: 0 direction (+1/-1, 0 unknown), 1 u extreme, 2 y at the extreme, 3 dwelling (1/0),
# 4 reversals, 5 largest dwell, 6 reversals with a dwell above the threshold, 7 have a sample,
# 8 u at the turning point, 9 y at the turning point, 10 torque at the extreme, 11 torque at the turning point,
# 12 samples of the current dwell written to the ring (travel, torque), 13 y the dwell's end is measured from
_N_STATE = 14


class Dwell(NamedTuple):
    """One reversal at which the load held still while the motor crossed the gap (degrees, N m).

    ``direction`` is the input's new direction (+1: rising, the right flank engages next; -1:
    falling, the left); ``travel_deg`` the input's travel from its turning point ``u_turn_deg``
    until the output moved beyond its band; ``y_turn_deg``, ``y_end_deg`` the output at the two
    ends; ``torque_turn_Nm``, ``torque_end_Nm`` the torque there as measured, ``torque_open_Nm`` its
    median over the middle half of the travel, where no flank touches (NaN without torque).
    """

    direction: float
    travel_deg: float
    u_turn_deg: float
    y_turn_deg: float
    y_end_deg: float
    torque_turn_Nm: float
    torque_end_Nm: float
    torque_open_Nm: float


@njit(cache=True, nogil=True)
def _middle_torque(ring, count, travel):  # pragma: no cover - compiled
    """The median torque of the ring's samples whose travel lies in the middle half of ``travel``
    (all of them where none does; NaN without a finite torque)."""
    n = min(count, ring.shape[0])
    mid = np.empty(n)
    k = 0
    for j in range(n):
        if 0.25 * travel <= ring[j, 0] <= 0.75 * travel and np.isfinite(ring[j, 1]):
            mid[k] = ring[j, 1]
            k += 1
    if k == 0:
        for j in range(n):
            if np.isfinite(ring[j, 1]):
                mid[k] = ring[j, 1]
                k += 1
    return np.median(mid[:k]) if k else np.nan


@njit(cache=True, nogil=True)
def _dwell_run(st, u, y, q, gap, h_u, h_y, threshold, events, ring):  # pragma: no cover - compiled
    """The dwell search over a block (the state ``st`` as laid out above, kept in locals in the loop);
    the dwells above ``threshold`` are written as rows of ``events`` (the fields of :class:`Dwell`),
    as many as fit; ``ring`` holds the current dwell's (travel, torque); returns how many were found."""
    d, u_ext, y_ext, dwelling, n_rev, max_dwell, n_gap, have, u_turn, y_turn, q_ext, q_turn = (
        st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9], st[10], st[11]
    )  # fmt: skip
    count = int(st[12])
    y_from = st[13]
    found = 0
    for i in range(u.shape[0]):
        ui, yi, qi = u[i], y[i], q[i]
        if gap[i] or have == 0.0:  # (re)start: no direction, no dwell
            d, u_ext, y_ext, q_ext, dwelling, have = 0.0, ui, yi, qi, 0.0, 1.0
            continue
        if d == 0.0:
            if abs(ui - u_ext) > h_u:
                d = 1.0 if ui > u_ext else -1.0
                u_ext, y_ext, q_ext = ui, yi, qi
            continue
        if (ui - u_ext) * d >= 0.0:  # on in the same direction: the extreme moves
            u_ext, y_ext, q_ext = ui, yi, qi
        elif abs(ui - u_ext) > h_u:  # turned back beyond the noise band: a reversal at the extreme
            n_rev += 1.0
            dwelling = 1.0
            count = 0
            u_turn, y_turn, q_turn = u_ext, y_ext, q_ext
            y_from = y_ext
            d = -d
            u_ext, y_ext, q_ext = ui, yi, qi
        if dwelling != 0.0:
            travel = abs(ui - u_turn)
            if travel > max_dwell:
                max_dwell = travel
            ring[count % ring.shape[0], 0] = travel
            ring[count % ring.shape[0], 1] = qi
            count += 1
            if (yi - y_from) * d < -h_y:  # the load coasts or creeps on the old way: no flank yet, the dwell goes on
                y_from = yi
            elif (yi - y_from) * d > h_y:  # the load follows the motor: the dwell ends
                if travel > threshold:
                    n_gap += 1.0
                    if found < events.shape[0]:
                        events[found, 0] = d
                        events[found, 1] = travel
                        events[found, 2] = u_turn
                        events[found, 3] = y_turn
                        events[found, 4] = yi
                        events[found, 5] = q_turn
                        events[found, 6] = qi
                        events[found, 7] = _middle_torque(ring, count, travel)
                        found += 1
                dwelling = 0.0
    st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9], st[10], st[11] = (
        d, u_ext, y_ext, dwelling, n_rev, max_dwell, n_gap, have, u_turn, y_turn, q_ext, q_turn
    )  # fmt: skip
    st[12] = count
    st[13] = y_from
    return found


def engagement_torques(
    dwells: list[Dwell] | tuple[Dwell, ...], torque_sign: float = 1.0
) -> tuple[float | None, float | None]:
    """The torque (N m, times ``torque_sign``) at which the left and the right flank engage: the median
    over the dwells towards each of the torque in their middle (None for a flank no dwell moved
    towards, or without torque).

    While the motor crosses the gap no flank touches, so the sensor reads its zero offset plus the
    friction between it and the flanks in that direction of motion (:mod:`online_backlash.simulation.two_mass_rig`
    simulates both): what it reads when the flank the motor moves towards begins to carry."""
    out: list[float | None] = []
    for direction in (-1.0, 1.0):
        opened = [
            torque_sign * d.torque_open_Nm
            for d in dwells
            if d.direction == direction and math.isfinite(d.torque_open_Nm)
        ]
        out.append(float(np.median(opened)) if opened else None)
    return out[0], out[1]


class DwellTracker:
    """Reversals of the input and the output's dwell after each (module docstring).

    The noise bands and the resolution of input and output are taken from the first
    :data:`PREFIX_SAMPLES` samples (:func:`still_band`, :func:`quantum_and_noise`; the search runs over
    them once they are in) unless ``band_u_deg`` / ``band_y_deg`` are set. Read before that, every
    attribute is that of the samples so far.

    Attributes
    ----------
    reversals_ : int
        Reversals of the input (through its noise band).
    dwells_showing_gap_ : int
        Reversals after which the load did not follow over more than ``DWELL_FACTOR`` output bands.
    max_dwell_deg_ : float
        The largest input travel with the load not following (within its band), degrees.
    dwells_ : list of Dwell
        The latest :data:`MAX_DWELLS` dwells that showed the gap, with the torque at their ends.
    """

    def __init__(self, band_u_deg: float | None = None, band_y_deg: float | None = None) -> None:
        self.band_u_deg = band_u_deg
        self.band_y_deg = band_y_deg
        self._st = np.zeros(_N_STATE)
        self._dwells: deque[Dwell] = deque(maxlen=MAX_DWELLS)
        self._resolution: tuple[float, float, float, float] | None = None  # quantum and noise of u, then of y
        self._ring = np.zeros((DWELL_SAMPLES, 2))
        self._prefix: list[np.ndarray] = []  # u, y, gap, torque of the first samples, until the bands are set
        self._settled_copy: tuple[int, DwellTracker] | None = None
        self._gap_next = False

    def update(
        self,
        u_deg: np.ndarray,
        y_deg: np.ndarray,
        after_gap: np.ndarray | None = None,
        torque_Nm: np.ndarray | None = None,
    ) -> None:
        """Learn consecutive samples (input and output, degrees; ``after_gap`` restarts the search;
        the torque, N m, where measured: kept at each dwell's ends)."""
        u = np.ascontiguousarray(u_deg, dtype=float)
        y = np.ascontiguousarray(y_deg, dtype=float)
        if u.size == 0:
            return
        gap = np.zeros(u.size, dtype=bool) if after_gap is None else np.array(after_gap, dtype=bool)
        q = np.full(u.size, np.nan) if torque_Nm is None else np.ascontiguousarray(torque_Nm, dtype=float)
        gap[0] |= self._gap_next
        self._gap_next = False
        if self._resolution is None:  # the prefix: held until it is complete, then searched at once
            self._prefix.append(np.vstack((u, y, gap, q)))
            self._settled_copy = None
            held = np.hstack(self._prefix)
            if held.shape[1] >= PREFIX_SAMPLES:
                self._settle(held)
            return
        self._search(u, y, gap, q)

    def _settle(self, held: np.ndarray) -> None:
        """Set the bands and the resolution from the first :data:`PREFIX_SAMPLES` held samples (all, where
        fewer are held) and search all of them."""
        u, y = held[0, :PREFIX_SAMPLES], held[1, :PREFIX_SAMPLES]
        self._prefix = []
        if u.size < 3:
            return
        self._resolution = (*quantum_and_noise(u), *quantum_and_noise(y))
        self.band_u_deg = still_band(u) if self.band_u_deg is None else self.band_u_deg
        self.band_y_deg = still_band(y) if self.band_y_deg is None else self.band_y_deg
        self._search(held[0], held[1], held[2].astype(bool), held[3])

    def _search(self, u: np.ndarray, y: np.ndarray, gap: np.ndarray, q: np.ndarray) -> None:
        events = np.empty((u.size // 2 + 1, len(Dwell._fields)))
        assert self.band_u_deg is not None and self.band_y_deg is not None
        found = _dwell_run(
            self._st, u, y, q, gap, self.band_u_deg, self.band_y_deg, self.threshold_deg, events, self._ring
        )
        self._dwells.extend(Dwell(*(float(v) for v in row)) for row in events[:found])

    def _now(self) -> DwellTracker:
        """This tracker, or before its prefix is complete, one that settled on the samples so far."""
        if self._resolution is not None or not self._prefix:
            return self
        held = np.hstack(self._prefix)
        if self._settled_copy is None or self._settled_copy[0] != held.shape[1]:
            copy = DwellTracker(self.band_u_deg, self.band_y_deg)
            copy._settle(held)
            self._settled_copy = (held.shape[1], copy)
        return self._settled_copy[1]

    def mark_gap(self) -> None:
        """The next sample does not continue the last one (a new log): the search restarts there."""
        self._gap_next = True

    @property
    def threshold_deg(self) -> float:
        """The dwell that shows the gap, degrees (NaN before the bands are known)."""
        band = self._now().band_y_deg if self._resolution is None else self.band_y_deg
        return math.nan if band is None else DWELL_FACTOR * band

    @property
    def reversals_(self) -> int:
        return int(self._now()._st[4])

    @property
    def dwells_showing_gap_(self) -> int:
        return int(self._now()._st[6])

    @property
    def max_dwell_deg_(self) -> float:
        return float(self._now()._st[5])

    @property
    def dwells_(self) -> list[Dwell]:
        return list(self._now()._dwells)

    @property
    def bands_deg(self) -> tuple[float | None, float | None]:
        """The still bands of input and output, degrees (None before a sample)."""
        now = self._now()
        return now.band_u_deg, now.band_y_deg

    @property
    def observable_(self) -> bool:
        """At least one reversal showed the gap (the load held still while the motor crossed it)."""
        return self.dwells_showing_gap_ >= 1

    @property
    def lower_bound_deg(self) -> float | None:
        """The play is at least this, degrees: the largest dwell that showed the gap (of those kept) less
        the input's and the output's noise bands (neither end of a dwell is placed more finely); None
        where no dwell showed the gap."""
        now = self._now()
        if not now._dwells:
            return None
        bound = max(d.travel_deg for d in now._dwells) - (now.band_u_deg or 0.0) - (now.band_y_deg or 0.0)
        return bound if bound > 0 else None

    @property
    def quantisation_deg(self) -> float:
        """Standard uncertainty of a play from the encoders' quantisation, which averaging over a log does
        not remove: ``sqrt((q_u^2 + q_y^2) / 12)``, degrees (NaN before 3 samples)."""
        resolution = self._now()._resolution
        if resolution is None:
            return math.nan
        q_u, _, q_y, _ = resolution
        return math.sqrt((q_u * q_u + q_y * q_y) / 12.0)

    @property
    def sample_resolution_deg(self) -> float:
        """Standard uncertainty of a play read from one pair of samples: quantisation and noise of both
        encoders, ``sqrt((q_u^2 + q_y^2) / 12 + n_u^2 + n_y^2)``, degrees (NaN before 3 samples)."""
        resolution = self._now()._resolution
        if resolution is None:
            return math.nan
        _, n_u, _, n_y = resolution
        return math.sqrt(self.quantisation_deg**2 + n_u * n_u + n_y * n_y)

    def state_dict(self) -> dict[str, Any]:
        """The tracker as plain JSON types (for a checkpoint); :meth:`from_state` restores it."""
        held = min(int(self._st[12]), DWELL_SAMPLES)  # the current dwell's samples in the ring
        return {
            "band_u_deg": self.band_u_deg, "band_y_deg": self.band_y_deg,
            "state": [v if math.isfinite(v) else None for v in self._st.tolist()],
            "resolution": None if self._resolution is None else list(self._resolution),
            "ring": [[v if math.isfinite(v) else None for v in row] for row in self._ring[:held].tolist()],
            "dwells": [[v if math.isfinite(v) else None for v in d] for d in self._dwells],
            "prefix": [[v if math.isfinite(v) else None for v in row] for row in np.hstack(self._prefix).tolist()]
            if self._prefix else None, "gap_next": self._gap_next,
        }  # fmt: skip

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> DwellTracker:
        """A tracker saved by :meth:`state_dict`."""
        tracker = cls(d["band_u_deg"], d["band_y_deg"])
        tracker._st = np.asarray([math.nan if v is None else v for v in d["state"]], dtype=float)
        ring = np.asarray([[math.nan if v is None else v for v in row] for row in d["ring"]], dtype=float).reshape(
            -1, 2
        )
        tracker._ring[: ring.shape[0]] = ring
        res = d["resolution"]
        tracker._resolution = None if res is None else (float(res[0]), float(res[1]), float(res[2]), float(res[3]))
        tracker._dwells.extend(Dwell(*(math.nan if v is None else float(v) for v in row)) for row in d["dwells"])
        if d["prefix"] is not None:
            tracker._prefix = [
                np.asarray([[math.nan if v is None else v for v in row] for row in d["prefix"]], dtype=float)
            ]
        tracker._gap_next = bool(d["gap_next"])
        return tracker

"""Which samples show the flanks fully engaged: a partial crossing of the gap belongs to neither flank line (issue 27).

Eq. (1) of Vörös (2010) has the load either on a flank or resting in the gap. A drive whose gap is
crossed in more than one step does a third thing: a geared train of several stages (a gearhead with
two stages, or a stage and a cable drive), or a load torque that holds the load against the far side
of the gap, lets the load follow the motor with only *part* of the gap crossed, until later in the
stroke it falls back onto the driving flank (or, slowing at the end of a stroke, runs ahead of it).
The gap of the train is the *full* crossing: the flanks bound it, so a partial crossing can make the
lost motion look smaller, never larger. A sample taken while the gap is partly crossed says nothing
about where either flank is; fitted into a flank line it tilts that line and the play read from it
falls short (the measured gearhead at full reaction torque: 1.52-1.79 deg where its other 45 runs read
1.76-1.91).

:class:`FullEngagement` marks those samples, from the motion alone (no torque, no model):

1. **Strokes and following.** A stroke runs from one reversal of the input (beyond its still band) to
   the next; within it the load *follows* once it has moved by more than its still band the way the
   motor goes (before that it dwells: the motor crosses the gap). This is
   :class:`~online_backlash.load_aware.DwellTracker`'s rule.
2. **The width of the gap at a load position.** While the load follows on flank ``s`` (right while the
   input rises), its lost motion ``L = u - y / m`` (``m`` the slope of eq. 1, from the data) minus that
   of the other flank's latest stroke at the same load position is the width of the gap there, wind-up
   included. Comparing the flanks *at the same position* cancels the transmission error common to both
   (eccentric encoders, tooth runout: a few tenths of a degree on the measured gearhead, as large as the
   partial crossings otherwise). Positions are compared in bins of :data:`BIN_DEG` of the (slope-scaled)
   load angle, one output revolution of them (:data:`N_BINS`), the other flank's record counting for
   :data:`PARTNER_STROKES` strokes.
3. **The full width** is the largest width the load keeps: the median over :data:`LEVEL_STROKES` strokes
   (a stream's latest; a whole record's around the stroke judged) of each stroke's largest bin-averaged
   width (a median, so that one stroke's glitch does not decide). It is known only as well as those strokes
   agree on it (a compliant drive driven faster in one stroke winds up more): the least full width is the
   median less two robust standard deviations of them.
4. **A partial crossing** is a following sample whose width falls short of the least full width by more
   than the least dwell the encoders can show (:data:`~.resolution.DWELL_FACTOR` output still bands, the
   kinematic observability's own threshold: a shortfall smaller than that cannot be told from noise).
   So is a sample at a position where the other flank was not fully engaged lately (its record there fell
   short, or its load only rested there): the play is the distance between the flanks *at one position*,
   and a flank sample without a fully engaged partner does not place it. A position the other flank has not
   reached lately (new ground, on a drive that turns on) says nothing either way: that sample counts. A
   dwelling sample (the load resting where the old flank left it) counts where neither flank's record at
   its position fell short or only rested.

Per sample the judgement is :data:`RESTING` (for the model to judge: eq. 1's third case), :data:`FOLLOWING`
or :data:`NO_FLANK` (on neither line). :class:`~.batch.VorosBacklash` and
:class:`~.backlash_rls.BacklashRLS` (``full_engagement=True``) fit their lines without the last, and the
per-reversal plays of the standard error (:class:`~.uncertainty.KinematicPlayScatter`) leave them out. On a
drive whose flanks are always fully engaged (the estimator's own model, a single stiff gap) the widths agree
within the encoders' resolution and only a few samples in the turning zones are on no line (0.5 % on the
kinematic rig); the plays are the paper's. On a compliant drive the full width is the flank wound up the
most: the kinematic play holds that wind-up (without a torque column wind-up and gap are not told apart),
and what was left out enters its uncertainty (:attr:`FullEngagement.engagement_std_deg_`).

**Batch and stream.** :meth:`FullEngagement.fit` reads a whole record: a stroke's partner at a position
is the nearest stroke of the other direction before or after it, and each stroke is judged against the
full width of the strokes around it, its own included, so the first strokes are judged too.
:meth:`FullEngagement.update` continues a stream sample by sample against the strokes completed so far (a
recursive estimator cannot wait for a stroke to end): after :meth:`~FullEngagement.fit` on a recursive
estimator's warm-start buffer, or on the first :data:`PREFIX_SAMPLES` samples it holds. The state is plain
JSON (:meth:`FullEngagement.state_dict`).

Units: degrees (load side).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from ..errors import InvalidParameterError, NotExcitedError
from .resolution import DWELL_FACTOR, still_band

__all__ = [
    "BIN_DEG", "FOLLOWING", "LEVEL_STROKES", "NO_FLANK", "N_BINS", "PARTNER_STROKES", "PREFIX_SAMPLES", "RESTING",
    "FullEngagement",
]  # fmt: skip

#: What :class:`FullEngagement` says of a sample: the load rests where the old flank left it (or the input has
#: not moved yet): eq. (1)'s third case, for the model to judge;
RESTING = 0
#: the load follows the motor on a fully engaged flank (the flank the input moves towards);
FOLLOWING = 1
#: on neither flank line: a partial crossing of the gap, or a position the other flank was not fully engaged at.
NO_FLANK = 2

#: Load positions closer than this (degrees of the slope-scaled load angle) are compared as one.
BIN_DEG = 0.5
#: Position bins kept per flank: one output revolution.
N_BINS = 720
#: The full width is the median of the largest widths of this many strokes: a stream's latest, a whole record's
#: around the stroke judged (an odd number: one odd stroke, a start-up's say, does not decide it).
LEVEL_STROKES = 5
#: The other flank's record at a position counts for this many strokes (the previous stroke of the other
#: direction, or the one before it).
PARTNER_STROKES = 3
#: Samples at the start of a record that give the still bands (10 s at 1 kHz, as the dwell tracker's).
PREFIX_SAMPLES = 10_000

# state vector: 0 direction (+1/-1, 0 unknown), 1 input extreme, 2 output the following is measured from,
# 3 following (1/0), 4 stroke index, 5 have a sample, 6 completed strokes, 7 and 8 the current stroke's sum of
# shortfalls and samples judged, then three rings of the latest LEVEL_STROKES strokes: their largest widths,
# sums of shortfalls, samples judged
_D, _EXT, _FROM, _FOLLOW, _K, _HAVE, _DONE, _SHORTFALL, _JUDGED_NOW, _RING = range(10)
_RING_SHORTFALL = _RING + LEVEL_STROKES
_RING_JUDGED = _RING_SHORTFALL + LEVEL_STROKES
_N_STATE = _RING_JUDGED + LEVEL_STROKES
# record fields per flank and position bin: sum and count of the lost motion of the load following, samples
# judged, of those short of the full width, the stroke that wrote them, the latest stroke the load was there
# at all (following or dwelling; -1: never)
_SUM, _CNT, _JUDGED, _SHORT, _STROKE, _VISIT = range(6)


@njit(cache=True, nogil=True)
def _valid(rec, side, b, k):  # pragma: no cover - compiled
    """Flank ``side`` has a record at bin ``b`` written within the last PARTNER_STROKES strokes before ``k``."""
    age = k - rec[side, _STROKE, b]
    return rec[side, _CNT, b] > 0.0 and 0.0 < age <= PARTNER_STROKES


@njit(cache=True, nogil=True)
def _unpaired(rec, side, b, k):  # pragma: no cover - compiled
    """Flank ``side``'s load was at bin ``b`` within the last PARTNER_STROKES strokes before ``k``, but did not
    follow the motor there: it rested (a dwell), the flank was not fully engaged at that position."""
    age = k - rec[side, _VISIT, b]
    return rec[side, _VISIT, b] >= 0.0 and 0.0 < age <= PARTNER_STROKES and not _valid(rec, side, b, k)


@njit(cache=True, nogil=True)
def _unplaced(rec, side, b, k):  # pragma: no cover - compiled
    """Flank ``side`` was not fully engaged at bin ``b`` lately: its record there fell short, or its load only
    rested there."""
    return (_valid(rec, side, b, k) and _short(rec, side, b)) or _unpaired(rec, side, b, k)


@njit(cache=True, nogil=True)
def _short(rec, side, b):  # pragma: no cover - compiled
    """The record of flank ``side`` at bin ``b`` fell short of the full width wherever it was judged."""
    return rec[side, _JUDGED, b] > 0.0 and rec[side, _SHORT, b] >= rec[side, _JUDGED, b]


@njit(cache=True, nogil=True)
def _least_full(widths):  # pragma: no cover - compiled
    """The least width at which the load counts as fully engaged, from strokes' largest ``widths``: their
    median (the full width) less two robust standard deviations of them (1.4826 MAD: the full width is known
    only as well as the strokes agree on it; a drive driven faster in one stroke winds up more); NaN
    without a finite one."""
    finite = widths[np.isfinite(widths)]
    if finite.size == 0:
        return np.nan
    full = np.median(finite)
    return full - 2.0 * 1.4826 * np.median(np.abs(finite - full))


@njit(cache=True, nogil=True)
def _ring(st):  # pragma: no cover - compiled
    """The largest widths of a stream's latest completed strokes (as many as there are, up to LEVEL_STROKES)."""
    return st[_RING : _RING + min(int(st[_DONE]), LEVEL_STROKES)].copy()


@njit(cache=True, nogil=True)
def _stroke_width(rec, k, d):  # pragma: no cover - compiled
    """The largest width of stroke ``k`` (direction ``d``): over the position bins it wrote, its mean lost
    motion minus the other flank's there (where that record counts), times the direction; -inf without one."""
    side = 1 if d > 0.0 else 0
    best = -np.inf
    for b in range(N_BINS):
        if rec[side, _STROKE, b] == k and rec[side, _CNT, b] > 0.0 and _valid(rec, 1 - side, b, k):
            mean = rec[side, _SUM, b] / rec[side, _CNT, b]
            best = max(best, d * (mean - rec[1 - side, _SUM, b] / rec[1 - side, _CNT, b]))
    return best


@njit(cache=True, nogil=True)
def _end_stroke(st, width, shortfall, judged):  # pragma: no cover - compiled
    """A stroke ended with largest width ``width``, ``judged`` samples judged and the sum of their
    shortfalls ``shortfall``: into the rings of the latest strokes."""
    slot = int(st[_DONE]) % LEVEL_STROKES
    st[_RING + slot], st[_RING_SHORTFALL + slot], st[_RING_JUDGED + slot] = width, shortfall, judged
    st[_DONE] += 1.0
    st[_SHORTFALL], st[_JUDGED_NOW] = 0.0, 0.0


@njit(cache=True, nogil=True, inline="always")
def _move(d, ext, frm, follow, k, have, ui, yi, gap, h_u, h_y):  # pragma: no cover - compiled
    """Step 1 of the module docstring for one sample: the input's direction and turning points, the stroke
    index, whether the load follows. The motion's state (direction, input extreme, output the following is
    measured from, following, stroke index, have a sample: the first six fields of the state vector) is
    passed and returned as values, so that the loops keep it in registers. Returns ``ended`` (True where the
    stroke that was running ended here: at a reversal, or at a gap; the state is then already that of the next
    one) and the new state."""
    if gap or have == 0.0:  # (re)start: no direction until the input moves beyond its band
        return d != 0.0, 0.0, ui, yi, 0.0, k, 1.0
    ended = False
    if d == 0.0:
        if abs(ui - ext) <= h_u:
            return False, d, ext, frm, follow, k, have
        d = 1.0 if ui > ext else -1.0
        ext, follow, k = ui, 1.0, k + 1.0
    elif (ui - ext) * d >= 0.0:
        ext = ui
    elif abs(ui - ext) > h_u:  # turned back beyond the band: a new stroke, the load dwells first
        ended = True
        d = -d
        ext, frm, follow, k = ui, yi, 0.0, k + 1.0
    if follow == 0.0:
        if (yi - frm) * d < -h_y:  # coasting the old way: the dwell goes on from here
            frm = yi
        elif (yi - frm) * d > h_y:
            follow = 1.0
    return ended, d, ext, frm, follow, k, have


@njit(cache=True, nogil=True)
def _classify(st, rec, u, y, gap, h_u, h_y, tol, out):  # pragma: no cover - compiled
    """The module docstring's rule over a block of a stream (the state ``st`` and the records ``rec``
    carried), each sample judged against the strokes completed before it: ``out[i]`` is :data:`RESTING`,
    :data:`FOLLOWING` or :data:`NO_FLANK`. The least full width changes only where a stroke ends: it is computed
    there (two medians of the ring), not for every sample judged. The state is held in locals over the block
    (written back at its end and where a stroke ends), not read and written in ``st`` for every sample."""
    least = _least_full(_ring(st))
    d, ext, frm, follow, k, have = st[_D], st[_EXT], st[_FROM], st[_FOLLOW], st[_K], st[_HAVE]
    shortfall, judged_now = st[_SHORTFALL], st[_JUDGED_NOW]
    for i in range(u.shape[0]):
        ui, yi = u[i], y[i]
        out[i] = RESTING
        k_was, d_was = k, d
        ended, d, ext, frm, follow, k, have = _move(d, ext, frm, follow, k, have, ui, yi, gap[i], h_u, h_y)
        if ended:
            _end_stroke(st, _stroke_width(rec, k_was, d_was), shortfall, judged_now)
            shortfall, judged_now = 0.0, 0.0
            least = _least_full(_ring(st))
        if d == 0.0:  # the input has not moved yet: nothing to judge
            continue
        side = 1 if d > 0.0 else 0
        other = 1 - side
        b = math.floor(yi / BIN_DEG) % N_BINS
        if follow == 0.0:  # dwelling where the old flank left the load
            out[i] = NO_FLANK if _unplaced(rec, side, b, k) or _unplaced(rec, other, b, k) else RESTING
            rec[side, _VISIT, b] = k
            continue
        rec[side, _VISIT, b] = k
        lost = ui - yi
        if rec[side, _STROKE, b] != k:
            rec[side, _SUM, b], rec[side, _CNT, b], rec[side, _JUDGED, b], rec[side, _SHORT, b] = 0.0, 0.0, 0.0, 0.0
            rec[side, _STROKE, b] = k
        rec[side, _SUM, b] += lost
        rec[side, _CNT, b] += 1.0
        if not _valid(rec, other, b, k):  # no partner: the other flank rested here (no), or was never here (yes)
            out[i] = NO_FLANK if _unpaired(rec, other, b, k) else FOLLOWING
            continue
        if not np.isfinite(least):  # nothing yet shows the full width
            out[i] = NO_FLANK
            continue
        width = d * (lost - rec[other, _SUM, b] / rec[other, _CNT, b])
        short = width < least - tol
        rec[side, _JUDGED, b] += 1.0
        rec[side, _SHORT, b] += 1.0 if short else 0.0
        judged_now += 1.0
        shortfall += least - width if short else 0.0
        out[i] = NO_FLANK if short or _short(rec, other, b) else FOLLOWING
    st[_D], st[_EXT], st[_FROM], st[_FOLLOW], st[_K], st[_HAVE] = d, ext, frm, follow, k, have
    st[_SHORTFALL], st[_JUDGED_NOW] = shortfall, judged_now


@njit(cache=True, nogil=True)
def _segment(st, u, y, gap, h_u, h_y, stroke, direction, follow):  # pragma: no cover - compiled
    """Step 1 over a whole record: per sample its stroke (-1 before the input moved), direction and
    whether the load follows; the state is left at the record's end."""
    d, ext, frm, fol, k, have = st[_D], st[_EXT], st[_FROM], st[_FOLLOW], st[_K], st[_HAVE]
    for i in range(u.shape[0]):
        _, d, ext, frm, fol, k, have = _move(d, ext, frm, fol, k, have, u[i], y[i], gap[i], h_u, h_y)
        moving = d != 0.0
        stroke[i] = int(k) if moving else -1
        direction[i] = d
        follow[i] = moving and fol != 0.0
    st[_D], st[_EXT], st[_FROM], st[_FOLLOW], st[_K], st[_HAVE] = d, ext, frm, fol, k, have


def _record_marks(
    stroke: np.ndarray, direction: np.ndarray, follow: np.ndarray, bins: np.ndarray, lost: np.ndarray, tol: float
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Steps 2-4 over a whole record segmented by :func:`_segment`, each stroke's partner the nearest
    stroke of the other direction before or after it, the full width including its own: the judgement of
    every sample, and the records the stream continues from (one per stroke and position bin the load
    followed at: ``stroke``, ``bin``, ``sum``, ``count``, ``judged``, ``short``; one per stroke and bin the
    load was at: ``visit_stroke``, ``visit_bin``; per stroke its largest width ``levels``, direction ``sense``,
    the sum of its samples' shortfalls ``shortfall`` and their number ``judged_per_stroke``)."""
    n_strokes = int(stroke.max()) + 1 if stroke.size and stroke.max() >= 0 else 0
    sense = np.zeros(max(n_strokes, 1))
    sense[stroke[stroke >= 0]] = direction[stroke >= 0]
    keys_all = stroke.astype(np.int64) * N_BINS + bins
    fol = np.flatnonzero(follow)
    keys, at = np.unique(keys_all[fol], return_inverse=True)
    visits = np.unique(keys_all[stroke >= 0])
    count = np.bincount(at, minlength=keys.size).astype(float)
    mean = np.bincount(at, weights=lost[fol], minlength=keys.size) / np.maximum(count, 1.0)
    k_key, b_key = keys // N_BINS, keys % N_BINS

    def find(table: np.ndarray, k: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The entry of stroke ``k`` at bin ``b`` in ``table`` (sorted keys): its index, -1 where there is none."""
        want = k * N_BINS + b
        pos = np.minimum(np.searchsorted(table, want), max(table.size - 1, 0))
        return np.where((table.size > 0) & (k >= 0) & (table[pos] == want), pos, -1)

    def nearest(table: np.ndarray, k: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The entry at bin ``b`` of the nearest stroke of the other direction than stroke ``k`` (the one before
        first), within PARTNER_STROKES: its index in ``table``, -1 where there is none."""
        found = np.full(k.size, -1)
        for step in (-1, 1, -3, 3):
            cand = find(table, k + step, b)
            other = (cand >= 0) & (sense[np.clip(k + step, 0, max(n_strokes - 1, 0))] == -sense[np.maximum(k, 0)])
            found = np.where((found < 0) & other, cand, found)
        return found

    partner = nearest(keys, k_key, b_key)
    width = np.where(partner >= 0, sense[k_key] * (mean - mean[np.maximum(partner, 0)]), -np.inf)
    levels = np.full(max(n_strokes, 1), -np.inf)
    np.maximum.at(levels, k_key, width)
    half = LEVEL_STROKES // 2
    least = np.array([_least_full(levels[max(0, k - half) : k + half + 1]) for k in range(levels.size)])
    # step 4 for the following samples: short of the full width, or paired with a record that was
    p = partner[at]
    judged = (p >= 0) & np.isfinite(least[stroke[fol]])
    w = sense[stroke[fol]] * (lost[fol] - mean[np.maximum(p, 0)])
    short = judged & (w < least[stroke[fol]] - tol)
    n_judged = np.bincount(at, weights=judged, minlength=keys.size)
    n_short = np.bincount(at, weights=short, minlength=keys.size)
    strokes = max(n_strokes, 1)
    judged_per_stroke = np.bincount(stroke[fol], weights=judged, minlength=strokes)
    shortfall = np.bincount(stroke[fol], weights=np.where(short, least[stroke[fol]] - w, 0.0), minlength=strokes)
    short_key = (n_judged > 0) & (n_short >= n_judged)
    # without a partner: the other flank rested at this position (no flank), or was never there (nothing says no)
    rested = (p < 0) & (nearest(visits, stroke[fol], bins[fol]) >= 0)
    no_flank = short | ((p >= 0) & (~judged | short_key[np.maximum(p, 0)])) | rested
    marks = np.full(stroke.size, RESTING, dtype=np.int8)
    marks[fol] = np.where(no_flank, NO_FLANK, FOLLOWING)

    def unplaced(k: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Stroke ``k``'s flank was not fully engaged at bin ``b``: its record fell short, or its load only
        rested there."""
        rec = find(keys, k, b)
        return np.where(rec >= 0, short_key[np.maximum(rec, 0)], find(visits, k, b) >= 0)

    # a dwelling sample: the old flank (the stroke before) and the new one (its own) at its position
    dwell = np.flatnonzero((stroke >= 0) & ~follow)
    dwelt = unplaced(stroke[dwell] - 1, bins[dwell]) | unplaced(stroke[dwell], bins[dwell])
    marks[dwell] = np.where(dwelt, NO_FLANK, RESTING)
    records = {
        "stroke": k_key, "bin": b_key, "sum": mean * count, "count": count, "judged": n_judged, "short": n_short,
        "visit_stroke": visits // N_BINS, "visit_bin": visits % N_BINS, "levels": levels[:n_strokes], "sense": sense,
        "shortfall": shortfall[:n_strokes], "judged_per_stroke": judged_per_stroke[:n_strokes],
    }  # fmt: skip
    return marks, records


def _median_finite(values: np.ndarray) -> float:
    """The median of the finite ``values`` (NaN without one)."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else math.nan


def _slope(u: np.ndarray, y: np.ndarray) -> float:
    """The slope of eq. (1) from the lines of the two directions of motion (:func:`~.batch._direction_guess`:
    the samples where input and output move together, one slope and an intercept per direction); the sign
    of the input-output correlation where they do not both move both ways."""
    from .batch import _direction_guess  # batch's estimator reads the marks of this module

    try:
        return float(_direction_guess(u, y).m_left)
    except NotExcitedError:
        return 1.0 if float(np.dot(np.diff(u), np.diff(y))) >= 0.0 else -1.0


class FullEngagement:
    """Judges which samples show a flank fully engaged; a partial crossing of the gap is on neither flank line
    (module docstring).

    Parameters
    ----------
    band_u_deg, band_y_deg : float, optional
        Still bands of input and output (degrees); by default from the first :data:`PREFIX_SAMPLES`
        samples of :meth:`fit` (:func:`~.resolution.still_band`, as the dwell tracker's).

    Attributes
    ----------
    slope_ : float
        The slope ``m`` of eq. (1) the lost motion ``u - y / m`` is read with (from the data).
    tolerance_deg_ : float
        The least shortfall that marks a partial crossing: :data:`~.resolution.DWELL_FACTOR` output
        still bands, degrees of input.
    full_width_deg_ : float
        The full width now (the median of the latest strokes' largest widths; NaN before one).
    shortfall_deg_, engagement_std_deg_ : float
        What the samples left out lately would take off the play, were they flank samples after all, and the
        play's standard uncertainty from it (the properties).
    settled_ : bool
        The bands are set: :meth:`update` judges as the samples come.

    Examples
    --------
    The estimator's own model: the load is always on a flank; only a few samples in the turning zones,
    where one flank's load rested and the other's followed, are on neither line.

    >>> from online_backlash.simulation.rig import simulate_rig
    >>> rec = simulate_rig(duration_s=20.0, play_deg=0.5)
    >>> fe = FullEngagement()
    >>> seen = fe.fit(rec.motor_deg / rec.ratio, rec.load_deg)
    >>> round(float(np.mean(seen == NO_FLANK)), 3), round(fe.full_width_deg_, 1), round(fe.shortfall_deg_, 3)
    (0.005, 0.5, 0.001)
    """

    def __init__(self, band_u_deg: float | None = None, band_y_deg: float | None = None) -> None:
        self.band_u_deg = band_u_deg
        self.band_y_deg = band_y_deg
        self._restart()
        self._fitted = False
        self._pending_gap = False
        self._prefix: list[np.ndarray] = []  # samples held by update before the bands are set

    def _restart(self) -> None:
        """No stroke and no record yet."""
        self._st = np.zeros(_N_STATE)
        self._st[_K] = -1.0
        self._rec = np.zeros((2, 6, N_BINS))
        self._rec[:, _VISIT, :] = -1.0

    def _check(self, u_deg: np.ndarray, y_deg: np.ndarray, after_gap: np.ndarray | None) -> tuple[np.ndarray, ...]:
        u = np.ascontiguousarray(u_deg, dtype=float)
        y = np.ascontiguousarray(y_deg, dtype=float)
        if u.ndim != 1 or u.shape != y.shape:
            shapes = f"{u.shape} and {y.shape}"
            raise InvalidParameterError(f"u and y must be 1-D arrays of equal length, got shapes {shapes}")
        gap = np.zeros(u.size, dtype=bool) if after_gap is None else np.array(after_gap, dtype=bool)
        if gap.shape != u.shape:
            raise InvalidParameterError(f"after_gap must be as long as u, got {gap.size} and {u.size}")
        if gap.size:
            gap[0] |= self._pending_gap
            self._pending_gap = False
        return u, y, gap

    def _scaled(self, y: np.ndarray) -> np.ndarray:
        """The output as the lost motion reads it, ``y / m`` (degrees of input)."""
        return y / self.slope_

    def fit(self, u_deg: np.ndarray, y_deg: np.ndarray, after_gap: np.ndarray | None = None) -> np.ndarray:
        """Judge a whole record (input and output, degrees; ``after_gap`` restarts the reading of the motion):
        per sample :data:`RESTING`, :data:`FOLLOWING` or :data:`NO_FLANK` (int8; :data:`NO_FLANK`: on neither
        flank line). Each stroke's partner at a
        position is the nearest stroke of the other direction before *or after* it, and it is judged against
        the full width of the strokes around it, its own included (module docstring): a whole record is known,
        so its first stroke is judged too. Starts afresh; the state is left at the record's end, so
        :meth:`update` continues it."""
        u, y, gap = self._check(u_deg, y_deg, after_gap)
        if u.size < 3:
            raise InvalidParameterError(f"need at least 3 samples to tell noise from motion, got {u.size}")
        head = slice(0, min(u.size, PREFIX_SAMPLES))
        self._h_u = still_band(u[head]) if self.band_u_deg is None else float(self.band_u_deg)
        self.slope_ = _slope(u, y)
        band_y = (still_band(y[head]) if self.band_y_deg is None else float(self.band_y_deg)) / abs(self.slope_)
        self._h_y, self.tolerance_deg_ = band_y, DWELL_FACTOR * band_y
        self._restart()
        yq = self._scaled(y)
        stroke = np.empty(u.size, dtype=np.int64)
        direction = np.empty(u.size)
        follow = np.empty(u.size, dtype=np.bool_)
        _segment(self._st, u, yq, gap, self._h_u, self._h_y, stroke, direction, follow)
        bins = np.floor(yq / BIN_DEG).astype(np.int64) % N_BINS
        marks, records = _record_marks(stroke, direction, follow, bins, u - yq, self.tolerance_deg_)
        self._continue_from(records)
        self._fitted = True
        return marks

    def _continue_from(self, records: dict[str, np.ndarray]) -> None:
        """The stream's records and ring after a whole record (:func:`_record_marks`): at every position
        each flank's latest stroke (where the load followed, where it was at all); the largest widths of the
        strokes completed."""
        sense = records["sense"]
        followed = ((_SUM, "sum"), (_CNT, "count"), (_JUDGED, "judged"), (_SHORT, "short"))
        for k, b, fields in (
            (records["stroke"], records["bin"], followed),
            (records["visit_stroke"], records["visit_bin"], ()),
        ):
            if not k.size:
                continue
            side = (sense[k] > 0).astype(np.int64)
            order = np.lexsort((k, b, side))  # by flank, bin, then stroke: the last of each group is the latest
            latest = np.ones(order.size, dtype=bool)
            latest[:-1] = (side[order][1:] != side[order][:-1]) | (b[order][1:] != b[order][:-1])
            pick = order[latest]
            for field, name in fields:
                self._rec[side[pick], field, b[pick]] = records[name][pick]
            self._rec[side[pick], _STROKE if fields else _VISIT, b[pick]] = k[pick]
        done = int(self._st[_K]) + (0 if self._st[_D] != 0.0 else 1)  # the strokes completed
        first = done - min(done, LEVEL_STROKES)
        self._st[_DONE] = first
        for j in range(first, done):
            _end_stroke(self._st, records["levels"][j], records["shortfall"][j], records["judged_per_stroke"][j])
        if done < records["levels"].size:  # the stroke still running at the record's end
            self._st[_SHORTFALL], self._st[_JUDGED_NOW] = records["shortfall"][done], records["judged_per_stroke"][done]

    def update(self, u_deg: np.ndarray, y_deg: np.ndarray, after_gap: np.ndarray | None = None) -> np.ndarray:
        """Judge the next samples of a stream against the strokes completed so far; the same arguments and
        result as :meth:`fit`. Before :meth:`fit` ran, the samples are held until :data:`PREFIX_SAMPLES` of
        them are judged by :meth:`fit` (the block that completes them gets its judgement from it; the blocks
        before are :data:`RESTING`, left to the model: nothing was known of them yet)."""
        u, y, gap = self._check(u_deg, y_deg, after_gap)
        if self._fitted:
            out = np.empty(u.size, dtype=np.int8)
            _classify(self._st, self._rec, u, self._scaled(y), gap, self._h_u, self._h_y, self.tolerance_deg_, out)
            return out
        self._prefix.append(np.vstack((u, y, gap)))
        held = np.hstack(self._prefix)
        if held.shape[1] < PREFIX_SAMPLES:
            return np.full(u.size, RESTING, dtype=np.int8)
        self._prefix = []
        return self.fit(held[0], held[1], held[2].astype(bool))[held.shape[1] - u.size :]

    def mark_gap(self) -> None:
        """The next sample does not continue the last one: the reading of the motion restarts there (the
        records of both flanks stay: the positions are the same drive's)."""
        self._pending_gap = True

    @property
    def settled_(self) -> bool:
        """The bands are set (:meth:`fit` ran): :meth:`update` judges a stream's samples as they come."""
        return self._fitted

    @property
    def shortfall_deg_(self) -> float:
        """How far, on average over the samples judged in the latest :data:`LEVEL_STROKES` strokes, the load fell
        short of the least full width where it was judged a partial crossing (0 for the others), degrees: about
        what the play would lose were those samples flank samples after all (each would pull its line in by its
        shortfall). 0 before a stroke was judged."""
        n = min(int(self._st[_DONE]), LEVEL_STROKES)
        judged = float(self._st[_RING_JUDGED : _RING_JUDGED + n].sum())
        return float(self._st[_RING_SHORTFALL : _RING_SHORTFALL + n].sum()) / judged if judged > 0 else 0.0

    @property
    def engagement_std_deg_(self) -> float:
        """The play's standard uncertainty from what was left out, degrees: without a torque column a partial
        crossing is not told apart from a wind-up that varies along the stroke, so the play lies between the
        full-engagement one (the rule was right: 0 off) and :attr:`shortfall_deg_` below it (it was wrong);
        reported at the full-engagement end of that interval, its root-mean-square error under a flat
        distribution over it is ``shortfall / sqrt 3`` (the GUM's type B evaluation of a bounded quantity)."""
        return self.shortfall_deg_ / math.sqrt(3.0)

    @property
    def full_width_deg_(self) -> float:
        """The full width now, degrees (NaN before a stroke showed one)."""
        return _median_finite(_ring(self._st))

    def state_dict(self) -> dict[str, Any]:
        """The classifier as plain JSON types (for an estimator's saved state); :meth:`from_state` restores it."""
        settled = None
        if self._fitted:
            settled = {"h_u": self._h_u, "h_y": self._h_y, "slope": self.slope_, "tolerance": self.tolerance_deg_}
        state = [v if math.isfinite(v) else None for v in self._st.tolist()]
        used = np.flatnonzero(self._rec[:, _VISIT, :].max(axis=0) >= 0)
        records = {str(int(b)): self._rec[:, :, b].tolist() for b in used}
        prefix = np.hstack(self._prefix).tolist() if self._prefix else None
        return {
            "band_u_deg": self.band_u_deg, "band_y_deg": self.band_y_deg, "settled": settled, "state": state,
            "records": records, "pending_gap": self._pending_gap, "prefix": prefix,
        }  # fmt: skip

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> FullEngagement:
        """A classifier saved by :meth:`state_dict`."""
        out = cls(d["band_u_deg"], d["band_y_deg"])
        if d["settled"] is not None:
            s = d["settled"]
            out._h_u, out._h_y, out.slope_, out.tolerance_deg_ = s["h_u"], s["h_y"], s["slope"], s["tolerance"]
            out._fitted = True
        out._st = np.asarray([-np.inf if v is None else v for v in d["state"]], dtype=float)
        for b, values in d["records"].items():
            out._rec[:, :, int(b)] = np.asarray(values, dtype=float)
        out._pending_gap = bool(d["pending_gap"])
        if d["prefix"] is not None:
            out._prefix = [np.asarray(d["prefix"], dtype=float)]
        return out

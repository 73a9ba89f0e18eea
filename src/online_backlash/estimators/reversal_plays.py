"""Per-reversal measurements of the play: which flank is engaged, where it is, and the output's noise.

* :class:`CyclePlays`: from the flank each sample is on and the flank offset it implies, one play
  per reversal (a stretch on one flank against the next stretch on the other), with the
  white-noise variance of each (successive differences, von Neumann 1941).
* :class:`MotionFlanks`: without torque, the flank a kinematic drive is on, from the input's
  motion (eq. 5-6 with the load at the far flank); :func:`kinematic_offsets`: the offsets of eq. (1).
* :class:`OutputNoise`: the output's white-noise variance from its second differences.
* :func:`kinematic_update`: the three of them on one block of a kinematic drive in one compiled
  pass (what :class:`~.uncertainty.KinematicPlayScatter` runs at every tick).

All stream block by block with state carried across blocks, and run compiled (numba, without
the GIL). The sums are those numpy's passes gave (:func:`_pairwise_sum` is numpy's summation
order, the output noise's sum of squares is still ``numpy.dot``), bit for bit, so the plays do not
depend on which path measured them. :mod:`.uncertainty` turns the plays into the standard error
of the play. Units: degrees (input units, load side).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..errors import InvalidParameterError
from .validation import finite_array

__all__ = ["MIN_SEGMENT_SAMPLES", "CyclePlays", "MotionFlanks", "OutputNoise", "kinematic_offsets", "kinematic_update"]

#: Samples a segment needs to count (fewer: a flicker of the flank signal, dropped).
MIN_SEGMENT_SAMPLES = 3

# A segment (one stretch on one flank) is a record of 8 floats, its fields in the order of the
# saved state's keys (CyclePlays.state_dict): the flank (-1/+1), the sum and count of its flank
# offsets, the sum of squared successive differences and their count (its white-noise variance,
# von Neumann 1941), whether it is not paired with the segment before (a gap, a new log), and its
# first and last offsets.
_FIELDS = ("side", "total", "count", "sq_diff", "n_diff", "after_break", "first", "last")
_CASTS = (int, float, int, float, int, bool, float, float)
_SIDE, _TOTAL, _COUNT, _SQ, _NDIFF, _BREAK, _FIRST, _LAST = range(8)
# CyclePlays' state vector: an open segment (1/0), a break pending for the next segment (1/0),
# then the open segment's record
_HAS_OPEN, _PENDING, _OPEN = 0, 1, 2
_N_STATE = _OPEN + len(_FIELDS)
# the exponent of the successive difference across two blocks, passed at run time: math.pow with a
# constant 2 compiles to x * x, which differs from Python's x ** 2 (libm pow) in the last bit of
# about 1 in 1000 values
_SQUARE = 2.0


@numba.njit(cache=True, nogil=True)
def _pairwise_sum(a):  # pragma: no cover - compiled
    """The sum of ``a`` in numpy's order (pairwise in blocks of 128, 8 accumulators; the
    ``pairwise_sum`` of numpy's ``loops_utils.h.src``), so it equals ``numpy.add.reduce`` bit for bit."""
    n = a.size
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[i]
        return res
    if n <= 128:
        r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
        i = 8
        while i < n - n % 8:
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise_sum(a[:n2]) + _pairwise_sum(a[n2:])


@numba.njit(cache=True, nogil=True)
def _run_sum(a, lo, hi):  # pragma: no cover - compiled
    """``numpy.add.reduceat``'s sum of ``a[lo:hi]``: the first value, plus the pairwise sum of the rest."""
    return a[lo] if hi - lo == 1 else a[lo] + _pairwise_sum(a[lo + 1 : hi])


@numba.njit(cache=True, nogil=True)
def _keep(segs, n, rec, min_samples):  # pragma: no cover - compiled
    """Append segment ``rec`` to the ``n`` closed segments ``segs`` (merged into the last one when on
    the same flank, as after a dropped flicker); a segment too short is dropped. Returns the
    segments (grown if full), their number, and whether a dropped segment carried a break."""
    if rec[_COUNT] < min_samples:
        return segs, n, rec[_BREAK] != 0.0
    if n > 0 and segs[n - 1, _SIDE] == rec[_SIDE] and rec[_BREAK] == 0.0:
        last = segs[n - 1]
        last[_TOTAL] += rec[_TOTAL]
        last[_COUNT] += rec[_COUNT]
        last[_SQ] += rec[_SQ] + 0.0
        last[_NDIFF] += rec[_NDIFF]
        last[_LAST] = rec[_LAST]
        return segs, n, False
    if n == segs.shape[0]:
        grown = np.empty((2 * n + 16, segs.shape[1]))
        grown[:n] = segs[:n]
        segs = grown
    segs[n, :] = rec
    return segs, n + 1, False


@numba.njit(cache=True, nogil=True)
def _close(st, segs, n, min_samples):  # pragma: no cover - compiled
    """Close the open segment (if any) into ``segs``; a dropped one's break is passed on."""
    if st[_HAS_OPEN] == 0.0:
        return segs, n
    st[_HAS_OPEN] = 0.0
    segs, n, carried = _keep(segs, n, st[_OPEN:], min_samples)
    if carried:
        st[_PENDING] = 1.0
    return segs, n


@numba.njit(cache=True, nogil=True)
def _mark_gap(st, segs, n, min_samples):  # pragma: no cover - compiled
    """The next sample does not continue the last: close the open segment, a break pending."""
    segs, n = _close(st, segs, n, min_samples)
    st[_PENDING] = 1.0
    return segs, n


@numba.njit(cache=True, nogil=True)
def _add_piece(st, segs, n, sides, vals, d2, lo, hi, min_samples, square):  # pragma: no cover - compiled
    """Add the engaged samples ``lo:hi`` of one stretch without a break (flank ``sides``, offsets
    ``vals``): each run on one flank is a piece that continues the open segment (the first run
    also across the step from the last block) or opens the next one."""
    if hi <= lo:
        return segs, n
    v, dd = vals[lo:hi], d2[lo:hi]  # slices: the loop vectorises
    for i in range(v.size - 1):
        d = v[i + 1] - v[i]
        dd[i] = d * d
    s, k = lo, 0
    while s < hi:
        e = s + 1
        while e < hi and sides[e] == sides[s]:
            e += 1
        d2[e - 1] = 0.0  # the step to the next run is not a successive difference of this one
        total, sq, count = _run_sum(vals, s, e), _run_sum(d2, s, e), float(e - s)
        pending = st[_PENDING]
        if st[_HAS_OPEN] != 0.0 and st[_OPEN + _SIDE] == sides[s]:
            rec = st[_OPEN:]
            rec[_TOTAL] += total
            rec[_COUNT] += count
            rec[_SQ] += sq + (math.pow(vals[s] - rec[_LAST], square) if k == 0 else 0.0)
            rec[_NDIFF] += (count - 1.0) + (1.0 if k == 0 else 0.0)
            rec[_LAST] = vals[e - 1]
        else:
            segs, n = _close(st, segs, n, min_samples)
            rec = st[_OPEN:]
            rec[_SIDE], rec[_TOTAL], rec[_COUNT], rec[_SQ] = float(sides[s]), total, count, sq
            rec[_NDIFF], rec[_BREAK], rec[_FIRST], rec[_LAST] = count - 1.0, pending, vals[s], vals[e - 1]
            st[_HAS_OPEN], st[_PENDING] = 1.0, 0.0
        s, k = e, k + 1
    return segs, n


@numba.njit(cache=True, nogil=True)
def _add_engaged(st, segs, n, sides, vals, cuts, n_cuts, m, min_samples, square):  # pragma: no cover - compiled
    """Add a block's ``m`` engaged samples (flank ``sides``, offsets ``vals``), with a break before
    engaged sample ``cuts[k]`` for each ``k < n_cuts``: the stretches between breaks one by one."""
    d2 = np.empty(m)
    lo = 0
    for k in range(n_cuts + 1):
        hi = cuts[k] if k < n_cuts else m
        if k > 0:
            segs, n = _mark_gap(st, segs, n, min_samples)
        segs, n = _add_piece(st, segs, n, sides, vals, d2, lo, hi, min_samples, square)
        lo = hi
    return segs, n


@numba.njit(cache=True, nogil=True)
def _feed(side, value, brk, st, segs, n, min_samples, square):  # pragma: no cover - compiled
    """:meth:`CyclePlays.update` on arrays: returns the closed segments, their number, and the index
    of the first engaged sample whose offset is not finite (-1: none; then nothing was changed)."""
    m_all = side.size
    vals = np.empty(m_all)
    sides = np.empty(m_all, dtype=np.int8)
    cuts = np.empty(m_all + 1, dtype=np.int64)  # engaged samples before each break
    m, n_cuts = 0, 0
    for j in range(m_all):
        if brk[j]:
            cuts[n_cuts] = m
            n_cuts += 1
        if side[j] != 0:
            v = value[j]
            if not math.isfinite(v):
                return segs, n, j
            vals[m] = v
            sides[m] = side[j]
            m += 1
    segs, n = _add_engaged(st, segs, n, sides, vals, cuts, n_cuts, m, min_samples, square)
    return segs, n, -1


class CyclePlays:
    """Per-reversal plays from flank engagements, fed block by block (streaming, memory per segment).

    Feed :meth:`update` with, per sample, the flank engaged (``-1`` left, ``+1`` right, ``0``
    none) and the flank offset that sample implies (degrees; see the module docstring: the left
    flank's offsets sit ``play`` above the right flank's). A segment still open at the end of a
    block continues in the next. :attr:`plays_deg` is one play per pair of adjacent segments on
    opposite flanks (one per reversal), :attr:`noise_var_deg2` the white-noise variance of each.

    Parameters
    ----------
    min_samples : int
        Samples a segment needs; shorter ones are dropped (and their neighbours, now on the same
        flank, merged).

    Examples
    --------
    >>> import numpy as np
    >>> side = np.repeat([1, -1, 1, -1], 5)                 # right, left, right, left
    >>> offset = np.where(side > 0, -0.3, 0.2)             # cR = 0.3, cL = 0.2
    >>> cp = CyclePlays()
    >>> cp.update(side[:7], offset[:7]); cp.update(side[7:], offset[7:])
    >>> cp.plays_deg.round(6).tolist()
    [0.5, 0.5, 0.5]
    """

    def __init__(self, min_samples: int = MIN_SEGMENT_SAMPLES) -> None:
        if isinstance(min_samples, bool) or not isinstance(min_samples, int) or min_samples < 1:
            raise InvalidParameterError(f"min_samples must be an int >= 1, got {min_samples!r}")
        self.min_samples = min_samples
        self._segs = np.empty((16, len(_FIELDS)))  # the closed segments' records, the first _n in use
        self._n = 0
        self._st = np.zeros(_N_STATE)

    def mark_gap(self) -> None:
        """The next sample does not continue the last (a gap, a new log): no play across it."""
        self._segs, self._n = _mark_gap(self._st, self._segs, self._n, self.min_samples)

    def update(self, side: np.ndarray, offset_deg: np.ndarray, breaks: np.ndarray | None = None) -> None:
        """Add a block: ``side`` (-1/0/+1 per sample), ``offset_deg`` (flank offset, degrees; read
        only where ``side != 0``), ``breaks`` (True where a sample does not continue the one before)."""
        side = np.asarray(side)
        offset = np.ascontiguousarray(offset_deg, dtype=float)
        if side.shape != offset.shape or side.ndim != 1:
            raise InvalidParameterError(
                f"side and offset_deg must be 1-D of equal length, got {side.shape} and {offset.shape}"
            )
        if side.size and (side.min() < -1 or side.max() > 1 or not np.issubdtype(side.dtype, np.integer)):
            raise InvalidParameterError("side must hold -1 (left flank), 0 (none) or +1 (right flank)")
        brk = np.zeros(side.size, dtype=np.bool_) if breaks is None else np.ascontiguousarray(breaks, dtype=np.bool_)
        if brk.shape != side.shape:
            raise InvalidParameterError(f"breaks must have the shape of side, {side.shape}, got {brk.shape}")
        self._feed(np.ascontiguousarray(side, dtype=np.int8), offset, brk)

    def _feed(self, side: np.ndarray, offset: np.ndarray, brk: np.ndarray) -> None:
        """:func:`_feed` on checked arrays (int8, float, bool); InvalidParameterError at a non-finite offset."""
        self._segs, self._n, bad = _feed(side, offset, brk, self._st, self._segs, self._n, self.min_samples, _SQUARE)
        if bad >= 0:
            raise InvalidParameterError(f"offset_deg on engaged samples has non-finite values, first at index {bad}")

    def _records(self) -> np.ndarray:
        """The segments so far (the open one kept as if closed now), one record per row."""
        segs = self._segs[: self._n].copy()
        if self._st[_HAS_OPEN] == 0.0:
            return segs
        segs, n, _ = _keep(segs, self._n, self._st[_OPEN:].copy(), self.min_samples)
        return segs[:n]

    def _pair_records(self) -> tuple[np.ndarray, np.ndarray]:
        """The segment records of every reversal: adjacent segments on opposite flanks, not across a break."""
        segs = self._records()
        a, b = segs[:-1], segs[1:]
        pair = (a[:, _SIDE] != b[:, _SIDE]) & (b[:, _BREAK] == 0.0)
        return a[pair], b[pair]

    def trim(self, keep_segments: int) -> None:
        """Forget all but the latest ``keep_segments`` closed segments (bounded memory on a stream
        whose old plays no longer count, e.g. weighted by a forgetting factor)."""
        if keep_segments < 1:
            raise InvalidParameterError(f"keep_segments must be >= 1, got {keep_segments!r}")
        drop = max(0, self._n - keep_segments)
        if drop:
            self._segs[: self._n - drop] = self._segs[drop : self._n]
            self._n -= drop

    @staticmethod
    def _as_dict(rec: np.ndarray) -> dict[str, object]:
        return {name: cast(value) for name, cast, value in zip(_FIELDS, _CASTS, rec.tolist())}

    @staticmethod
    def _as_record(d: dict[str, object]) -> list[float]:
        return [float(d.get(name, math.nan)) for name in _FIELDS]  # type: ignore[arg-type]

    def state_dict(self) -> dict[str, object]:
        """The segments so far as JSON types (for an estimator's saved state; :meth:`from_state`)."""
        return {
            "min_samples": self.min_samples, "closed": [self._as_dict(rec) for rec in self._segs[: self._n]],
            "open": self._as_dict(self._st[_OPEN:]) if self._st[_HAS_OPEN] else None,
            "pending_break": bool(self._st[_PENDING]),
        }  # fmt: skip

    @classmethod
    def from_state(cls, d: dict[str, object]) -> CyclePlays:
        """A :class:`CyclePlays` continuing from :meth:`state_dict`."""
        out = cls(int(d["min_samples"]))  # type: ignore[call-overload]
        closed = [cls._as_record(s) for s in d["closed"]]  # type: ignore[attr-defined]
        out._segs = np.array(closed, dtype=float).reshape(-1, len(_FIELDS)) if closed else out._segs
        out._n = len(closed)
        if d["open"] is not None:
            out._st[_OPEN:] = cls._as_record(d["open"])  # type: ignore[arg-type]
            out._st[_HAS_OPEN] = 1.0
        out._st[_PENDING] = float(bool(d["pending_break"]))
        return out

    @property
    def n_segments(self) -> int:
        """Segments so far (the open one included when long enough)."""
        return len(self._records())

    @property
    def plays_deg(self) -> np.ndarray:
        """One play per reversal: left segment's mean offset minus the adjacent right segment's, degrees."""
        a, b = self._pair_records()
        return (a[:, _TOTAL] / a[:, _COUNT] - b[:, _TOTAL] / b[:, _COUNT]) * np.where(a[:, _SIDE] < 0, 1.0, -1.0)

    @property
    def noise_var_deg2(self) -> np.ndarray:
        """White-noise variance of each play of :attr:`plays_deg`, degrees squared."""
        a, b = self._pair_records()
        return self._mean_var(a) + self._mean_var(b)

    @staticmethod
    def _mean_var(segs: np.ndarray) -> np.ndarray:
        """White-noise variance of each segment's mean offset: ``sigma^2 / count``, ``sigma^2 = sum(d^2) / (2 n_d)``
        (0 for a segment without successive differences)."""
        n_diff = segs[:, _NDIFF]
        has = n_diff > 0
        out = np.zeros(len(segs))
        out[has] = segs[has, _SQ] / (2.0 * n_diff[has]) / segs[has, _COUNT]
        return out


@numba.njit(inline="always")
def _flank_step(x, gap, d, turn, ext, rev, started, travel, hysteresis):  # pragma: no cover - compiled
    """One sample ``x`` of :class:`MotionFlanks`: its flank (-1/0/+1) and the new state
    ``direction, turn, extreme, reversed, started``."""
    if gap or started == 0.0:
        d, turn, ext, rev, started = 0.0, x, x, 0.0, 1.0
    if d == 0.0:
        if abs(x - turn) > hysteresis:
            d = 1.0 if x > turn else -1.0
            ext = x
    elif d > 0.0:
        if x > ext:
            ext = x
        elif ext - x > hysteresis:
            d, turn, ext, rev = -1.0, ext, x, 1.0
    else:
        if x < ext:
            ext = x
        elif x - ext > hysteresis:
            d, turn, ext, rev = 1.0, ext, x, 1.0
    side = np.int8(d) if rev != 0.0 and abs(x - turn) > travel else np.int8(0)
    return side, d, turn, ext, rev, started


@numba.njit(cache=True, nogil=True)
def _flanks(u, travel, hysteresis, state, gap):  # pragma: no cover - compiled
    """Flank per sample from the motion of ``u`` (see :class:`MotionFlanks`); ``state`` =
    ``[direction, turn, extreme, reversed, started]`` carried across calls."""
    n = u.size
    side = np.zeros(n, dtype=np.int8)
    d, turn, ext, rev, started = state[0], state[1], state[2], state[3], state[4]
    for i in range(n):
        side[i], d, turn, ext, rev, started = _flank_step(u[i], gap[i], d, turn, ext, rev, started, travel, hysteresis)
    state[0], state[1], state[2], state[3], state[4] = d, turn, ext, rev, started
    return side


class MotionFlanks:
    """The flank a kinematic drive is on, from the motion of the input alone (streaming).

    A reversal is declared when ``u`` comes back more than ``hysteresis`` from its running
    extreme (the extreme is the turning point). After it, once ``u`` has travelled more than
    ``travel`` from the turning point, the load is taken as pushed by the flank ahead: the
    left (-1) while ``u`` falls, the right (+1) while it rises (eq. 5-6). Before the first
    reversal, and after a gap until the next, where the load sits in the gap is unknown: 0.

    Parameters
    ----------
    travel : float
        Input travel after a reversal before a flank counts as engaged, degrees: the play plus a
        margin for the compliance ramp.
    hysteresis : float
        Motion back from the extreme that makes a reversal, degrees (above the input's noise).
    """

    def __init__(self, travel: float, hysteresis: float) -> None:
        if not (travel >= 0 and hysteresis > 0 and math.isfinite(travel) and math.isfinite(hysteresis)):
            raise InvalidParameterError(f"need travel >= 0 and hysteresis > 0 (degrees), got {travel} and {hysteresis}")
        self.travel = float(travel)
        self.hysteresis = float(hysteresis)
        self._state = np.zeros(5)

    @staticmethod
    def _settings(play_deg: float) -> tuple[float, float]:
        play = max(abs(float(play_deg)), 1e-9)
        return 1.5 * play, 0.25 * play

    @classmethod
    def for_play(cls, play_deg: float) -> MotionFlanks:
        """Settings for a drive of play ``play_deg``: reversal at a quarter of the play, a flank
        engaged after one and a half plays of travel (past the gap and most of a compliance ramp)."""
        travel, hysteresis = cls._settings(play_deg)
        return cls(travel=travel, hysteresis=hysteresis)

    def follow(self, play_deg: float) -> None:
        """Take the settings of :meth:`for_play` for a new play (wear), keeping the motion state."""
        travel, hysteresis = self._settings(play_deg)
        if not (math.isfinite(travel) and travel > 0):
            raise InvalidParameterError(f"the play must be a finite angle, got {play_deg!r} degrees")
        self.travel, self.hysteresis = travel, hysteresis

    def update(self, u: np.ndarray, gap: np.ndarray | None = None) -> np.ndarray:
        """The flank (-1/0/+1, int8) of each sample of a block of ``u`` (degrees); ``gap`` marks
        samples that do not continue the one before."""
        u = finite_array("u", u)
        return _flanks(u, self.travel, self.hysteresis, self._state, _gap_flags(gap, u.shape))


def _gap_flags(gap: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """``gap`` as a contiguous bool array of ``shape`` (all False for None); InvalidParameterError if it differs."""
    g = np.zeros(shape, dtype=np.bool_) if gap is None else np.ascontiguousarray(gap, dtype=np.bool_)
    if g.shape != shape:
        raise InvalidParameterError(f"gap must have the shape of the samples, {shape}, got {g.shape}")
    return g


@numba.njit(inline="always")
def _offset(x, v, side, m_left, m_right, level):  # pragma: no cover - compiled
    """The flank offset of eq. (1) of input ``x`` and output ``v`` on flank ``side`` (-1/+1), 0 on none:
    ``(v - level) / m - x``, minus where the flank lies at output ``level``."""
    if side < 0:
        return (v - level) / m_left - x
    if side > 0:
        return (v - level) / m_right - x
    return 0.0


@numba.njit(cache=True, nogil=True)
def _offsets(u, y, side, m_left, m_right, level):  # pragma: no cover - compiled
    """:func:`kinematic_offsets` on arrays."""
    out = np.empty(side.size)
    for i in range(side.size):
        out[i] = _offset(u[i], y[i], side[i], m_left, m_right, level)
    return out


def kinematic_offsets(
    u: np.ndarray, y: np.ndarray, side: np.ndarray, m_left: float, m_right: float, level_deg: float = 0.0
) -> np.ndarray:
    """Flank offsets of eq. (1): ``y / mL - u`` on the left flank (``= cL``), ``y / mR - u`` on the
    right (``= -cR``), degrees; 0 where no flank is engaged. Read at the output level ``level_deg``
    (``(y - level) / m - u``: minus where the flank lies at that level), the play they give is the flanks'
    distance there."""
    u, y = np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(y, dtype=float)
    return _offsets(u, y, np.ascontiguousarray(side, dtype=np.int8), float(m_left), float(m_right), float(level_deg))


@numba.njit(cache=True, nogil=True)
def _second_differences(y, gaps, tail):  # pragma: no cover - compiled
    """:meth:`OutputNoise.update`'s differences: the second differences of each stretch of ``y``
    between gaps (``gaps``: the indices of the samples after one, in order; numpy's
    ``diff(piece, 2)``; the first stretch continues ``tail``, the last samples of the previous block,
    unless the block starts with a gap), one stretch after the other. Returns them, where each
    stretch's end in them, and the new tail."""
    n = y.size
    out = np.empty(n)
    ends = np.empty(gaps.size + 1, dtype=np.int64)
    continues = gaps.size == 0 or gaps[0] != 0
    m, k, start, g = 0, 0, 0, 0 if continues else 1
    while start < n:
        end = gaps[g] if g < gaps.size else n
        g += 1
        head = tail if start == 0 and continues else tail[:0]  # the stretch is head + y[start:end]
        h = head.size
        if h + end - start >= 3:
            for j in range(min(h, h + end - start - 2)):  # the differences that reach into the head
                a, b = head[j], head[j + 1] if j + 1 < h else y[start + j + 1 - h]
                c = head[j + 2] if j + 2 < h else y[start + j + 2 - h]
                out[m] = (c - b) - (b - a)
                m += 1
            o, ys = out[m:], y[start:end]  # slices: the loop vectorises
            for j in range(ys.size - 2):
                o[j] = (ys[j + 2] - ys[j + 1]) - (ys[j + 1] - ys[j])
            m += max(0, ys.size - 2)
            ends[k] = m
            k += 1
        if end - start >= 2 or h == 0:
            tail = y[max(start, end - 2) : end].copy()
        else:
            tail = np.array([head[h - 1], y[start]])
        start = end
    return out, ends[:k], tail


class OutputNoise:
    """The white-noise variance of a signal from its second differences, fed block by block.

    ``var = mean((y[t+1] - 2 y[t] + y[t-1])^2) / 6``: a smooth motion sampled fast has almost no
    second difference, white noise (or quantisation) of variance ``s^2`` gives ``6 s^2``
    (the difference-based variance estimators of von Neumann 1941 and Rice 1984). Gaps restart
    the differences.
    """

    def __init__(self) -> None:
        self.total = 0.0
        self.count = 0
        self._tail = np.empty(0)

    def update(self, y: np.ndarray, gap: np.ndarray | None = None) -> None:
        """Add a block of the signal (``gap``: True where a sample does not continue the one before)."""
        y = np.ascontiguousarray(y, dtype=float)
        if y.size:
            self._add(*_second_differences(y, np.flatnonzero(_gap_flags(gap, y.shape)), self._tail))

    def _add(self, d2: np.ndarray, ends: np.ndarray, tail: np.ndarray) -> None:
        """Sum the squared second differences of each stretch (``numpy.dot``, one per stretch as
        numpy's passes summed them) and keep the block's tail."""
        start = 0
        for end in ends.tolist():
            piece = d2[start:end]
            self.total += float(np.dot(piece, piece))
            self.count += end - start
            start = end
        self._tail = tail

    @property
    def var_deg2(self) -> float:
        """The noise variance, squared units of the signal (NaN before 3 samples)."""
        return self.total / (6.0 * self.count) if self.count else math.nan


@numba.njit(cache=True, nogil=True)
def _kinematic_pass(  # pragma: no cover - compiled
    u, y, gap, left_out, travel, hysteresis, flank_state, m_left, m_right, level, st, segs, n, min_samples, square, tail
):
    """:func:`kinematic_update`'s compiled part: one loop over the samples (flank, offset, engaged
    samples kept, but those ``left_out``), the segments of the engaged samples, the output's second differences. Returns
    the closed segments and their number, the first sample with a non-finite input, output or
    offset (-1: none; else nothing was changed), the second differences, their stretches' ends and
    the new tail."""
    size = u.size
    vals = np.empty(size)
    sides = np.empty(size, dtype=np.int8)
    cuts = np.empty(size + 1, dtype=np.int64)
    gaps = np.empty(size, dtype=np.int64)
    d, turn, ext, rev, started = flank_state[0], flank_state[1], flank_state[2], flank_state[3], flank_state[4]
    m, n_cuts = 0, 0
    for i in range(size):
        x, v, g = u[i], y[i], gap[i]
        if not (math.isfinite(x) and math.isfinite(v)):
            return segs, n, i, vals[:0], cuts[:0], tail
        if g:
            cuts[n_cuts] = m
            gaps[n_cuts] = i
            n_cuts += 1
        side, d, turn, ext, rev, started = _flank_step(x, g, d, turn, ext, rev, started, travel, hysteresis)
        if side != 0 and not left_out[i]:
            off = _offset(x, v, side, m_left, m_right, level)
            if not math.isfinite(off):
                return segs, n, i, vals[:0], cuts[:0], tail
            vals[m] = off
            sides[m] = side
            m += 1
    flank_state[0], flank_state[1], flank_state[2], flank_state[3], flank_state[4] = d, turn, ext, rev, started
    segs, n = _add_engaged(st, segs, n, sides, vals, cuts, n_cuts, m, min_samples, square)
    d2, ends, tail = _second_differences(y, gaps[:n_cuts], tail)
    return segs, n, -1, d2, ends, tail


def kinematic_update(
    flanks: MotionFlanks, cycles: CyclePlays, noise: OutputNoise, u: np.ndarray, y: np.ndarray, gap: np.ndarray | None,
    m_left: float, m_right: float, left_out: np.ndarray | None = None, level_deg: float = 0.0,
) -> None:  # fmt: skip
    """One block of a kinematic drive, input ``u`` and output ``y`` (degrees, load side), in one
    compiled pass: the flank of each sample (``flanks``, :meth:`MotionFlanks.update`), its offset
    with the slopes ``m_left``, ``m_right`` (eq. 1, :func:`kinematic_offsets`) into ``cycles``
    (:meth:`CyclePlays.update`, ``gap`` as the breaks) and the output's second differences into
    ``noise`` (:meth:`OutputNoise.update`): the same state as those calls give, bit for bit.
    ``left_out`` (True: a sample on no flank, a partial crossing of the gap,
    :class:`~.full_engagement.FullEngagement`) takes samples out of the flanks' segments; the offsets are
    read at the output level ``level_deg`` (the level the estimator reads its play at).

    Raises
    ------
    InvalidParameterError
        If the arrays differ in shape, ``u`` or ``y`` has a non-finite value, or an engaged
        sample's offset is not finite (a slope of 0); nothing is changed then.
    """
    u = np.ascontiguousarray(u, dtype=float)
    y = np.ascontiguousarray(y, dtype=float)
    if u.ndim != 1 or u.shape != y.shape:
        raise InvalidParameterError(f"u and y must be 1-D arrays of equal length, got shapes {u.shape} and {y.shape}")
    if not u.size:
        return
    g = _gap_flags(gap, u.shape)
    out = np.zeros(u.shape, dtype=np.bool_) if left_out is None else np.ascontiguousarray(left_out, dtype=np.bool_)
    if out.shape != u.shape:
        raise InvalidParameterError(f"left_out must have the shape of the samples, {u.shape}, got {out.shape}")
    segs, n, bad, d2, ends, tail = _kinematic_pass(
        u, y, g, out, flanks.travel, flanks.hysteresis, flanks._state, float(m_left), float(m_right), float(level_deg),
        cycles._st, cycles._segs, cycles._n, cycles.min_samples, _SQUARE, noise._tail,
    )  # fmt: skip
    cycles._segs, cycles._n = segs, n
    if bad >= 0:
        which = "u or y" if not (math.isfinite(u[bad]) and math.isfinite(y[bad])) else "the flank offset (slope 0?)"
        raise InvalidParameterError(f"{which} has a non-finite value at sample {bad}")
    noise._add(d2, ends, tail)

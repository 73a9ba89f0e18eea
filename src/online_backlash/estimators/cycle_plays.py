"""Per-reversal measurements of the play: which flank is engaged, where it is, and the output's noise.

* :class:`CyclePlays`: from the flank each sample is on and the flank offset it implies, one play
  per reversal (a stretch on one flank against the next stretch on the other), with the
  white-noise variance of each (successive differences, von Neumann 1941).
* :class:`MotionFlanks`: without torque, the flank a kinematic drive is on, from the input's
  motion (eq. 5-6 with the load at the far flank); :func:`kinematic_offsets`: the offsets of eq. (1).
* :class:`OutputNoise`: the output's white-noise variance from its second differences.

All stream block by block with state carried across blocks. :mod:`.uncertainty` turns the plays
into the standard error of the play. Units: degrees (input units, load side).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numba
import numpy as np

from ..errors import InvalidParameterError
from ._base import finite_array

__all__ = ["MIN_SEGMENT_SAMPLES", "CyclePlays", "MotionFlanks", "OutputNoise", "kinematic_offsets"]

#: Samples a segment needs to count (fewer: a flicker of the flank signal, dropped).
MIN_SEGMENT_SAMPLES = 3


@dataclass
class _Segment:
    """One stretch on one flank: the sum and count of its flank offsets and the sum of squared
    successive differences (their white-noise variance, von Neumann 1941); ``after_break``: not
    paired with the segment before (a gap, a new log)."""

    side: int
    total: float
    count: int
    sq_diff: float
    n_diff: int
    after_break: bool
    first: float = math.nan
    last: float = math.nan

    @property
    def mean(self) -> float:
        return self.total / self.count

    @property
    def mean_var(self) -> float:
        """White-noise variance of :attr:`mean`: ``sigma^2 / count``, ``sigma^2 = sum(d^2) / (2 n_d)``."""
        return self.sq_diff / (2.0 * self.n_diff) / self.count if self.n_diff else 0.0

    def absorb(self, other: _Segment, adjacent: bool = False) -> None:
        """Continue this segment with ``other`` (same flank); ``adjacent``: its first sample
        follows this one's last (the step between them is a successive difference too)."""
        self.total += other.total
        self.count += other.count
        self.sq_diff += other.sq_diff + ((other.first - self.last) ** 2 if adjacent else 0.0)
        self.n_diff += other.n_diff + int(adjacent)
        self.last = other.last


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
        self._closed: list[_Segment] = []
        self._open: _Segment | None = None
        self._pending_break = False

    def mark_gap(self) -> None:
        """The next sample does not continue the last (a gap, a new log): no play across it."""
        self._close()
        self._pending_break = True

    def update(self, side: np.ndarray, offset_deg: np.ndarray, breaks: np.ndarray | None = None) -> None:
        """Add a block: ``side`` (-1/0/+1 per sample), ``offset_deg`` (flank offset, degrees; read
        only where ``side != 0``), ``breaks`` (True where a sample does not continue the one before)."""
        side = np.asarray(side)
        offset = np.asarray(offset_deg, dtype=float)
        if side.shape != offset.shape or side.ndim != 1:
            raise InvalidParameterError(f"side and offset_deg must be 1-D of equal length, got {side.shape} and {offset.shape}")
        if side.size and (side.min() < -1 or side.max() > 1 or not np.issubdtype(side.dtype, np.integer)):
            raise InvalidParameterError("side must hold -1 (left flank), 0 (none) or +1 (right flank)")
        cuts = [0, side.size]
        if breaks is not None:
            cuts[1:1] = np.flatnonzero(np.asarray(breaks, dtype=bool)).tolist()
        for k, (start, end) in enumerate(itertools.pairwise(cuts)):
            if k > 0:
                self.mark_gap()
            self._add(side[start:end], offset[start:end])

    def _add(self, side: np.ndarray, offset: np.ndarray) -> None:
        nz = np.flatnonzero(side)
        if not nz.size:
            return
        s = side[nz]
        values = finite_array("offset_deg on engaged samples", offset[nz])
        starts = np.concatenate(([0], np.flatnonzero(np.diff(s)) + 1))
        totals = np.add.reduceat(values, starts)
        counts = np.diff(np.append(starts, s.size))
        d2 = np.append(np.diff(values) ** 2, 0.0)  # d2[i]: (v[i+1] - v[i])^2, within a segment unless i ends one
        d2[starts[1:] - 1] = 0.0
        sq = np.add.reduceat(d2, starts)
        firsts, lasts = values[starts].tolist(), values[np.append(starts[1:], s.size) - 1].tolist()
        pieces = zip(s[starts].tolist(), totals.tolist(), counts.tolist(), sq.tolist(), firsts, lasts)
        for k, (seg_side, total, count, sq_diff, first, last) in enumerate(pieces):
            piece = _Segment(seg_side, total, count, sq_diff, count - 1, self._pending_break, first, last)
            if self._open is not None and self._open.side == seg_side:
                self._open.absorb(piece, adjacent=k == 0)
            else:
                self._close()
                self._open = piece
                self._pending_break = False

    def _close(self) -> None:
        seg, self._open = self._open, None
        if seg is not None:
            self._pending_break = self._keep(self._closed, seg) or self._pending_break

    def _keep(self, segs: list[_Segment], seg: _Segment) -> bool:
        """Append ``seg`` to ``segs`` (merged into the last one when on the same flank, as after a
        dropped flicker); a segment too short is dropped: True if it carried a break to pass on."""
        if seg.count < self.min_samples:
            return seg.after_break
        last = segs[-1] if segs else None
        if last is not None and last.side == seg.side and not seg.after_break:
            last.absorb(seg)
        else:
            segs.append(seg)
        return False

    def _segments(self) -> list[_Segment]:
        segs = [_Segment(**vars(s)) for s in self._closed]
        if self._open is not None:
            self._keep(segs, _Segment(**vars(self._open)))
        return segs

    def _pairs(self) -> list[tuple[_Segment, _Segment]]:
        segs = self._segments()
        return [(a, b) for a, b in itertools.pairwise(segs) if a.side != b.side and not b.after_break]

    def trim(self, keep_segments: int) -> None:
        """Forget all but the latest ``keep_segments`` closed segments (bounded memory on a stream
        whose old plays no longer count, e.g. weighted by a forgetting factor)."""
        if keep_segments < 1:
            raise InvalidParameterError(f"keep_segments must be >= 1, got {keep_segments!r}")
        del self._closed[:-keep_segments]

    def state_dict(self) -> dict[str, object]:
        """The segments so far as JSON types (for an estimator's saved state; :meth:`from_state`)."""
        return {
            "min_samples": self.min_samples, "closed": [vars(s).copy() for s in self._closed],
            "open": None if self._open is None else vars(self._open).copy(), "pending_break": self._pending_break,
        }  # fmt: skip

    @classmethod
    def from_state(cls, d: dict[str, object]) -> CyclePlays:
        """A :class:`CyclePlays` continuing from :meth:`state_dict`."""
        out = cls(int(d["min_samples"]))  # type: ignore[call-overload]
        out._closed = [_Segment(**s) for s in d["closed"]]  # type: ignore[attr-defined]
        out._open = None if d["open"] is None else _Segment(**d["open"])  # type: ignore[arg-type]
        out._pending_break = bool(d["pending_break"])
        return out

    @property
    def n_segments(self) -> int:
        """Segments so far (the open one included when long enough)."""
        return len(self._segments())

    @property
    def plays_deg(self) -> np.ndarray:
        """One play per reversal: left segment's mean offset minus the adjacent right segment's, degrees."""
        return np.asarray([(a.mean - b.mean) * (1 if a.side < 0 else -1) for a, b in self._pairs()], dtype=float)

    @property
    def noise_var_deg2(self) -> np.ndarray:
        """White-noise variance of each play of :attr:`plays_deg`, degrees squared."""
        return np.asarray([a.mean_var + b.mean_var for a, b in self._pairs()], dtype=float)


@numba.njit(cache=True)
def _flanks(
    u: np.ndarray, travel: float, hysteresis: float, state: np.ndarray, gap: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Flank per sample from the motion of ``u`` (see :class:`MotionFlanks`); ``state`` =
    ``[direction, turn, extreme, reversed, started]`` carried across calls."""
    n = u.size
    side = np.zeros(n, dtype=np.int8)
    d, turn, ext, rev, started = state[0], state[1], state[2], state[3], state[4]
    for i in range(n):
        x = u[i]
        if gap[i] or started == 0.0:
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
        if rev != 0.0 and abs(x - turn) > travel:
            side[i] = np.int8(d)
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

    @classmethod
    def for_play(cls, play_deg: float) -> MotionFlanks:
        """Settings for a drive of play ``play_deg``: reversal at a quarter of the play, a flank
        engaged after one and a half plays of travel (past the gap and most of a compliance ramp)."""
        play = max(abs(float(play_deg)), 1e-9)
        return cls(travel=1.5 * play, hysteresis=0.25 * play)

    def update(self, u: np.ndarray, gap: np.ndarray | None = None) -> np.ndarray:
        """The flank (-1/0/+1, int8) of each sample of a block of ``u`` (degrees); ``gap`` marks
        samples that do not continue the one before."""
        u = finite_array("u", u)
        g = np.zeros(u.size, dtype=np.bool_) if gap is None else np.ascontiguousarray(gap, dtype=np.bool_)
        if g.shape != u.shape:
            raise InvalidParameterError(f"gap must have the shape of u, {u.shape}, got {g.shape}")
        return _flanks(u, self.travel, self.hysteresis, self._state, g)


def kinematic_offsets(u: np.ndarray, y: np.ndarray, side: np.ndarray, m_left: float, m_right: float) -> np.ndarray:
    """Flank offsets of eq. (1): ``y / mL - u`` on the left flank (``= cL``), ``y / mR - u`` on the
    right (``= -cR``), degrees; 0 where no flank is engaged."""
    out = np.zeros(side.shape)
    for flank, m in ((-1, m_left), (1, m_right)):
        on = np.flatnonzero(side == flank)
        out[on] = y[on] / m - u[on]
    return out


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
        y = np.asarray(y, dtype=float)
        if not y.size:
            return
        g = np.zeros(y.size, dtype=bool) if gap is None else np.asarray(gap, dtype=bool)
        cuts = [0, *np.flatnonzero(g).tolist(), y.size]
        for k, (start, end) in enumerate(itertools.pairwise(cuts)):
            continues = k == 0 and not g[0]  # the block's first piece follows the last block's tail
            piece = np.concatenate((self._tail, y[start:end])) if continues else y[start:end]
            if piece.size >= 3:
                d2 = np.diff(piece, 2)
                self.total += float(np.dot(d2, d2))
                self.count += int(d2.size)
            self._tail = piece[-2:]

    @property
    def var_deg2(self) -> float:
        """The noise variance, squared units of the signal (NaN before 3 samples)."""
        return self.total / (6.0 * self.count) if self.count else math.nan

"""The compiled per-reversal plays equal numpy's passes bit for bit, whatever the blocks.

:mod:`online_backlash.estimators.reversal_plays` runs compiled (one pass per block for a kinematic
drive); its sums follow numpy's summation order so that the plays, their noise and hence the
reported ``backlash_std_deg`` are the numbers the numpy implementation gave. The reference below
is that implementation (segments as objects, ``numpy.add.reduceat``, ``numpy.diff``,
``numpy.dot``), kept here as the oracle.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass

import numpy as np
import pytest

from online_backlash.errors import InvalidParameterError
from online_backlash.estimators.reversal_plays import (
    CyclePlays,
    MotionFlanks,
    OutputNoise,
    kinematic_offsets,
    kinematic_update,
)
from online_backlash.estimators.uncertainty import KinematicPlayScatter


# -- the numpy reference -------------------------------------------------------------------------
@dataclass
class _Seg:
    side: int
    total: float
    count: int
    sq_diff: float
    n_diff: int
    after_break: bool
    first: float
    last: float

    def absorb(self, other: _Seg, adjacent: bool = False) -> None:
        self.total += other.total
        self.count += other.count
        self.sq_diff += other.sq_diff + ((other.first - self.last) ** 2 if adjacent else 0.0)
        self.n_diff += other.n_diff + int(adjacent)
        self.last = other.last


class RefCyclePlays:
    def __init__(self, min_samples: int = 3) -> None:
        self.min_samples, self.closed, self.open, self.pending = min_samples, [], None, False

    def mark_gap(self) -> None:
        self._close()
        self.pending = True

    def update(self, side, offset, breaks=None) -> None:
        cuts = [0, side.size]
        if breaks is not None:
            cuts[1:1] = np.flatnonzero(breaks).tolist()
        for k, (a, b) in enumerate(itertools.pairwise(cuts)):
            if k > 0:
                self.mark_gap()
            self._add(side[a:b], offset[a:b])

    def _add(self, side, offset) -> None:
        nz = np.flatnonzero(side)
        if not nz.size:
            return
        s, values = side[nz], np.ascontiguousarray(offset[nz], dtype=float)
        starts = np.concatenate(([0], np.flatnonzero(np.diff(s)) + 1))
        totals, counts = np.add.reduceat(values, starts), np.diff(np.append(starts, s.size))
        d2 = np.append(np.diff(values) ** 2, 0.0)
        d2[starts[1:] - 1] = 0.0
        sq = np.add.reduceat(d2, starts)
        lasts = values[np.append(starts[1:], s.size) - 1]
        for k, i in enumerate(range(starts.size)):
            piece = _Seg(int(s[starts[i]]), float(totals[i]), int(counts[i]), float(sq[i]), int(counts[i]) - 1,
                         self.pending, float(values[starts[i]]), float(lasts[i]))  # fmt: skip
            if self.open is not None and self.open.side == piece.side:
                self.open.absorb(piece, adjacent=k == 0)
            else:
                self._close()
                self.open, self.pending = piece, False

    def _close(self) -> None:
        seg, self.open = self.open, None
        if seg is not None:
            self.pending = self._keep(self.closed, seg) or self.pending

    def _keep(self, segs, seg) -> bool:
        if seg.count < self.min_samples:
            return seg.after_break
        if segs and segs[-1].side == seg.side and not seg.after_break:
            segs[-1].absorb(seg)
        else:
            segs.append(seg)
        return False

    def state_dict(self) -> dict:
        return {"min_samples": self.min_samples, "closed": [vars(s).copy() for s in self.closed],
                "open": None if self.open is None else vars(self.open).copy(),
                "pending_break": self.pending}  # fmt: skip

    def pairs(self):
        segs = [_Seg(**vars(s)) for s in self.closed]
        if self.open is not None:
            self._keep(segs, _Seg(**vars(self.open)))
        return [(a, b) for a, b in itertools.pairwise(segs) if a.side != b.side and not b.after_break]

    @property
    def plays_deg(self) -> np.ndarray:
        return np.asarray(
            [(a.total / a.count - b.total / b.count) * (1 if a.side < 0 else -1) for a, b in self.pairs()], dtype=float
        )

    @property
    def noise_var_deg2(self) -> np.ndarray:
        def mean_var(s):
            return s.sq_diff / (2.0 * s.n_diff) / s.count if s.n_diff else 0.0

        return np.asarray([mean_var(a) + mean_var(b) for a, b in self.pairs()], dtype=float)


class RefOutputNoise:
    def __init__(self) -> None:
        self.total, self.count, self.tail = 0.0, 0, np.empty(0)

    def update(self, y, gap) -> None:
        cuts = [0, *np.flatnonzero(gap).tolist(), y.size]
        for k, (a, b) in enumerate(itertools.pairwise(cuts)):
            piece = np.concatenate((self.tail, y[a:b])) if k == 0 and not gap[0] else y[a:b]
            if piece.size >= 3:
                d2 = np.diff(piece, 2)
                self.total += float(np.dot(d2, d2))
                self.count += int(d2.size)
            self.tail = piece[-2:]


def ref_offsets(u, y, side, m_left, m_right):
    out = np.zeros(side.shape)
    for flank, m in ((-1, m_left), (1, m_right)):
        on = np.flatnonzero(side == flank)
        out[on] = y[on] / m - u[on]
    return out


# -- inputs ----------------------------------------------------------------------------------------
def flank_blocks(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flanks in runs of 1-400 samples (flickers, stretches of none), offsets with noise, breaks."""
    lengths = rng.integers(1, rng.choice([5, 40, 400]), size=400)
    side = np.repeat(rng.choice([-1, 0, 1], size=400), lengths)[:n]
    offset = np.where(side > 0, -0.3, 0.2) + rng.standard_normal(side.size) * 10.0 ** rng.integers(-6, 0)
    return side, offset, rng.random(side.size) < rng.choice([0.0, 0.002, 0.02])


def cuts_of(rng: np.random.Generator, n: int, k: int) -> list[tuple[int, int]]:
    cuts = np.sort(rng.choice(np.arange(1, n), size=min(k, n - 1), replace=False)).tolist() if n > 1 else []
    return list(itertools.pairwise([0, *cuts, n]))


def kinematic_log(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sine-driven drive with play (flanks 0.2 left, 0.3 right), noise and dropouts (1 kHz)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = 3.0 * np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 0.13 * t)
    y = np.where(np.cos(2 * np.pi * 0.7 * t) > 0, u - 0.2, u + 0.3) * 0.999 + rng.standard_normal(n) * 1e-3
    return u, y, rng.random(n) < 3e-4


# -- tests -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(40))
def test_cycle_plays_equal_the_numpy_passes_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    side, offset, breaks = flank_blocks(rng, int(rng.integers(2, 4000)))
    min_samples = int(rng.choice([1, 3, 5]))
    ours, ref = CyclePlays(min_samples), RefCyclePlays(min_samples)
    for a, b in cuts_of(rng, side.size, int(rng.integers(0, 8))):
        if rng.random() < 0.1:
            ours.mark_gap()
            ref.mark_gap()
        ours.update(side[a:b].astype(rng.choice([np.int8, np.int64])), offset[a:b], breaks[a:b])
        ref.update(side[a:b], offset[a:b], breaks[a:b])
    assert ours.plays_deg.tobytes() == ref.plays_deg.tobytes()
    assert ours.noise_var_deg2.tobytes() == ref.noise_var_deg2.tobytes()
    assert json.dumps(ours.state_dict()) == json.dumps(ref.state_dict())  # checkpoints keep their format


def test_a_saved_state_continues_as_if_never_saved():
    rng = np.random.default_rng(11)
    side, offset, breaks = flank_blocks(rng, 3000)
    whole, first = CyclePlays(), CyclePlays()
    whole.update(side, offset, breaks)
    first.update(side[:1700], offset[:1700], breaks[:1700])
    resumed = CyclePlays.from_state(json.loads(json.dumps(first.state_dict())))
    resumed.update(side[1700:], offset[1700:], breaks[1700:])
    first.update(side[1700:], offset[1700:], breaks[1700:])
    assert resumed.plays_deg.tobytes() == first.plays_deg.tobytes() and resumed.n_segments == whole.n_segments
    np.testing.assert_allclose(resumed.plays_deg, whole.plays_deg, rtol=1e-12)  # other blocks: the same to rounding
    resumed.trim(3)
    assert resumed.state_dict()["closed"] == first.state_dict()["closed"][-3:]


def test_output_noise_equals_the_numpy_passes_in_any_blocks():
    rng = np.random.default_rng(5)
    for _ in range(60):
        y, gap = rng.standard_normal(200), rng.random(200) < 0.15
        ours, ref = OutputNoise(), RefOutputNoise()
        for a, b in cuts_of(rng, y.size, int(rng.integers(0, 60))):
            ours.update(y[a:b], gap[a:b])
            ref.update(y[a:b], gap[a:b])
        assert (ours.total, ours.count) == (ref.total, ref.count)
    with pytest.raises(InvalidParameterError, match="shape"):
        OutputNoise().update(np.zeros(4), np.zeros(3, dtype=bool))


@pytest.mark.parametrize("tick", [997, 10_000, 40_000])
def test_the_compiled_kinematic_pass_equals_the_separate_numpy_steps(tick):
    """What KinematicPlayScatter measures per tick (flanks, offsets, plays, output noise) is what
    the numpy passes gave on a log with dropouts: the same plays, noise, hence the same std."""
    u, y, gap = kinematic_log(120_000, seed=tick)
    ours = KinematicPlayScatter()
    flanks, ref, noise = MotionFlanks.for_play(0.5), RefCyclePlays(), RefOutputNoise()
    for k, a in enumerate(range(0, u.size, tick)):
        sl, play = slice(a, a + tick), 0.5 + 1e-4 * k  # the estimate moves from tick to tick
        ours.update(u[sl], y[sl], gap[sl], play, 0.999, 1.001)
        flanks.travel, flanks.hysteresis = MotionFlanks.for_play(play).travel, MotionFlanks.for_play(play).hysteresis
        side = flanks.update(u[sl], gap[sl])
        ref.update(side, ref_offsets(u[sl], y[sl], side, 0.999, 1.001), gap[sl])
        noise.update(y[sl], gap[sl])
    assert ours.plays_deg.size > 100
    assert ours.plays_deg.tobytes() == ref.plays_deg.tobytes()
    assert ours.noise_var_deg2.tobytes() == ref.noise_var_deg2.tobytes()
    assert (ours.noise.total, ours.noise.count) == (noise.total, noise.count)
    assert np.all((ours.plays_deg > 0.3) & (ours.plays_deg < 0.6))  # the left flank above the right


def test_the_kinematic_pass_does_not_depend_on_the_blocks_beyond_rounding():
    u, y, gap = kinematic_log(60_000, seed=3)
    results = []
    for tick in (1000, 7919, 60_000):
        scatter = KinematicPlayScatter()
        for a in range(0, u.size, tick):
            scatter.update(u[a : a + tick], y[a : a + tick], gap[a : a + tick], 0.5, 0.999, 1.001)
        results.append(scatter)
    for other in results[1:]:
        np.testing.assert_allclose(other.plays_deg, results[0].plays_deg, rtol=0, atol=1e-12)
        assert other.noise.count == results[0].noise.count
        assert other.noise.var_deg2 == pytest.approx(results[0].noise.var_deg2, rel=1e-12)


def test_kinematic_update_refuses_non_finite_samples_and_changes_nothing():
    u, y, gap = kinematic_log(5000, seed=1)
    flanks, cycles, noise = MotionFlanks.for_play(0.5), CyclePlays(), OutputNoise()
    kinematic_update(flanks, cycles, noise, u[:3000], y[:3000], gap[:3000], 1.0, 1.0)
    before = (json.dumps(cycles.state_dict()), flanks._state.tobytes(), noise.total, noise.count)
    bad = y[3000:].copy()
    bad[123] = math.nan
    with pytest.raises(InvalidParameterError, match="non-finite value at sample 123"):
        kinematic_update(flanks, cycles, noise, u[3000:], bad, gap[3000:], 1.0, 1.0)
    assert (json.dumps(cycles.state_dict()), flanks._state.tobytes(), noise.total, noise.count) == before
    with pytest.raises(InvalidParameterError, match="equal length"):
        kinematic_update(flanks, cycles, noise, u[:10], y[:9], None, 1.0, 1.0)


def test_kinematic_offsets_follow_eq_1():
    u = np.array([0.0, 1.0, 2.0, 3.0])
    y = np.array([5.0, 5.0, 1.0, 4.0])
    side = np.array([0, -1, 1, -1], dtype=np.int8)
    assert kinematic_offsets(u, y, side, 0.5, 2.0).tolist() == [0.0, 5.0 / 0.5 - 1.0, 1.0 / 2.0 - 2.0, 4.0 / 0.5 - 3.0]


def test_the_step_across_two_blocks_is_squared_as_python_squares_it():
    """The successive difference across two blocks enters as Python's ``d ** 2`` (libm pow), which
    differs from ``d * d`` in the last bit for about 1 value in 1000: the saved segments still match."""
    rng = np.random.default_rng(0)
    d = next(x for x in rng.standard_normal(100_000).tolist() if x**2 != x * x)
    ours, ref = CyclePlays(), RefCyclePlays()
    for offset in (np.zeros(4), np.full(4, d)):
        ours.update(np.ones(4, dtype=np.int8), offset)
        ref.update(np.ones(4, dtype=np.int8), offset)
    assert ours.state_dict()["open"]["sq_diff"] == ref.state_dict()["open"]["sq_diff"] == d**2

"""The full-engagement judgement of a long block made in a worker thread (issue 31): the same estimates, bit for bit.

:class:`BacklashRLS` with ``full_engagement`` learns a block of :data:`AHEAD_MIN_SAMPLES` or more in pieces, the
next piece judged in a worker thread while its compiled loop learns the current one. Held here against the same
samples in blocks too short for it (judged on the caller's thread) on a drive the estimator does not assume (the
two-mass rig: compliance, friction, partial crossings of the gap), snapshots inside the pieces and at their
ends included.
"""

from __future__ import annotations

import itertools
import json
import threading

import numpy as np

from online_backlash import BacklashRLS
from online_backlash.estimators import _judge_ahead
from online_backlash.estimators.full_engagement import FullEngagement
from online_backlash.log_fit import KINEMATIC
from online_backlash.simulation.two_mass_rig import simulate_two_mass

SHORT = 4_000  # below AHEAD_MIN_SAMPLES: judged on the caller's thread


def _samples() -> tuple[np.ndarray, np.ndarray]:
    rec = simulate_two_mass(duration_s=150.0, play_deg=0.6, seed=4)
    return rec.motor_deg / rec.ratio, rec.load_deg


def _learn(u: np.ndarray, y: np.ndarray, block: int, every: int) -> tuple[list, dict]:
    """Learn ``u, y`` in blocks of ``block`` samples, the estimate every ``every`` samples of the stream."""
    est = BacklashRLS(**KINEMATIC)
    found = []
    for lo in range(0, u.size, block):
        n = min(block, u.size - lo)
        ticks = np.arange(every - lo % every, n + 1, every, dtype=np.int64)
        found += [
            (lo + int(t), at) for t, at in zip(ticks, est.learn_many(u[lo : lo + n], y[lo : lo + n], snapshot_at=ticks))
        ]
    return found, est.state_dict()


def test_pieces_cover_the_block_in_order() -> None:
    for n in (0, 5, _judge_ahead.AHEAD_MIN_SAMPLES - 1, _judge_ahead.AHEAD_MIN_SAMPLES, 65_536, 1_000_003):
        parts = _judge_ahead.pieces(n)
        assert parts[0][0] == 0 and parts[-1][1] == n
        assert all(a[1] == b[0] and a[0] < a[1] for a, b in itertools.pairwise(parts))
        assert (len(parts) == 1) == (n < _judge_ahead.AHEAD_MIN_SAMPLES)


def test_long_blocks_judged_in_a_worker_give_the_same_estimates(monkeypatch) -> None:
    u, y = _samples()
    threads: set[str] = set()
    update = FullEngagement.update

    def spy(self: FullEngagement, *args, **kwargs):  # type: ignore[no-untyped-def]
        threads.add(threading.current_thread().name)
        return update(self, *args, **kwargs)

    monkeypatch.setattr(FullEngagement, "update", spy)
    short = _learn(u, y, SHORT, 3_001)
    assert threads == {threading.main_thread().name}
    long = _learn(u, y, 40_000, 3_001)
    assert any(name.startswith("online-backlash-judge") for name in threads)  # the judgement left the caller's thread
    assert [t for t, _ in long[0]] == [t for t, _ in short[0]]
    assert repr(long[0]) == repr(short[0])  # every estimate, bit for bit (NaN compares equal in repr)
    assert json.dumps(long[1], sort_keys=True) == json.dumps(short[1], sort_keys=True)

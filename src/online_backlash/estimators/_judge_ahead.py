"""The next samples judged in a worker thread while the estimator learns the current ones (issue 31).

:class:`~.backlash_rls.BacklashRLS` with ``full_engagement`` judges every sample
(:meth:`FullEngagement.update <.full_engagement.FullEngagement.update>`) before its compiled loop learns it.
The judgement reads only the samples and the judge's own state, never the estimator's, so a long block is
cut into pieces and the judgement of piece ``j + 1`` runs in a worker thread while the loop learns piece
``j`` (both compiled ``nogil``: on two cores at once). The judge sees the same calls in the same order as
without the thread, one at a time, and so does the loop: the same results, bit for bit.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

#: Blocks shorter than this are judged on the caller's thread (a live stream's chunks: no hand-off at all).
AHEAD_MIN_SAMPLES = 16_384
#: The first piece is this fraction of the block, each next one twice the one before (the last one takes the
#: rest): the judgement costs about a third of the loop per sample, so a piece is judged before the loop has
#: learned the one before it, and the caller's thread judges only the first sixteenth itself.
FIRST_PIECE = 16

_pool: tuple[int, ThreadPoolExecutor] | None = None
_pool_lock = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """The judging thread of this process (a new one in a forked child, which has none of its parent's threads)."""
    global _pool
    with _pool_lock:
        if _pool is None or _pool[0] != os.getpid():
            _pool = (os.getpid(), ThreadPoolExecutor(max_workers=1, thread_name_prefix="online-backlash-judge"))
        return _pool[1]


def pieces(n: int) -> list[tuple[int, int]]:
    """The pieces ``(lo, hi)`` a block of ``n`` samples is learned in, in order: one below
    :data:`AHEAD_MIN_SAMPLES`; else the first ``n //`` :data:`FIRST_PIECE`, each next twice the one before,
    the last taking what a next one would not fill."""
    if n < AHEAD_MIN_SAMPLES:
        return [(0, n)]
    out: list[tuple[int, int]] = []
    lo, size = 0, n // FIRST_PIECE
    while lo < n:
        hi = n if lo + 3 * size > n else lo + size
        out.append((lo, hi))
        lo, size = hi, 2 * size
    return out


def learn_judged(
    judge: Callable[[int, int], np.ndarray], learn: Callable[[int, int, np.ndarray], None], n: int
) -> None:
    """``learn(lo, hi, judge(lo, hi))`` over the :func:`pieces` of ``n`` samples, in order, the judgement of
    the next piece made in the worker thread while the current one is learned; an exception of either is
    raised here (the worker's judgement still running is waited for first)."""
    parts = pieces(n)
    seen = judge(*parts[0])
    for j, (lo, hi) in enumerate(parts):
        ahead: Future[np.ndarray] | None = _worker().submit(judge, *parts[j + 1]) if j + 1 < len(parts) else None
        try:
            learn(lo, hi, seen)
        finally:
            if ahead is not None:
                seen = ahead.result()

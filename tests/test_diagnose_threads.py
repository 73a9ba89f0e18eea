"""``diagnose`` runs its least squares on one BLAS thread, whatever the caller's setting.

Its truncated eigen-solves can move a nearly collinear term's direction across the cut-off when a
multi-threaded BLAS sums in another order (run20 of the shared recordings changed its third term
with the thread count), so the loop pins BLAS to one thread for a result that is the same on a
machine whatever its core count (``loop.ONE_BLAS_THREAD``).
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from online_backlash.diagnostics import loop
from online_backlash.simulation import synthetic


def _blas_threads() -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_the_loop_runs_on_one_blas_thread_and_restores_the_callers_setting(monkeypatch):
    seen: list[list[int]] = []
    estimate = loop.estimate_initial_state

    def spy(*args, **kwargs):
        seen.append(_blas_threads())
        return estimate(*args, **kwargs)

    monkeypatch.setattr(loop, "estimate_initial_state", spy)
    t, m, y, q = synthetic.TWO_MASS_INJECTORS["compliance"](seed=1, duration_s=20.0)
    with threadpool_limits(limits=2, user_api="blas"):
        outside = _blas_threads()
        d = loop.diagnose_arrays(t, m, y, 30.0, torque_Nm=q)
        assert _blas_threads() == outside  # the caller's setting is back
    assert seen and all(n == 1 for n in seen[0]) and seen[0]
    assert outside and max(outside) == 2  # the test does set more than one thread outside
    assert np.isfinite(d.rms_after_deg)

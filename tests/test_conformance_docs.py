"""The example estimator of ``docs/estimators.md`` passes the conformance suite, run from the page itself.

The page's first Python block (the estimator) and its second (the check and a fit) are executed as written,
so the page and the code cannot drift apart; the example with its gap hook emptied must fail the suite.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from online_backlash.estimators.conformance import check_estimator
from online_backlash.model import BacklashParams, simulate_backlash

PAGE = Path(__file__).resolve().parents[1] / "docs" / "estimators.md"


def _blocks() -> list[str]:
    return re.findall(r"^```python\n(.*?)^```$", PAGE.read_text(encoding="utf-8"), flags=re.M | re.S)


def _run(source: str, namespace: dict[str, Any] | None = None) -> dict[str, Any]:
    namespace = {"__name__": "estimators_md"} if namespace is None else namespace
    exec(compile(source, str(PAGE), "exec"), namespace)
    return namespace


def test_the_example_estimator_of_the_page_passes_the_conformance_suite():
    estimator, usage = _blocks()
    assert "class PaperRLS(RegressorRLS)" in estimator and "check_estimator(" in usage
    code = estimator.strip().splitlines()
    assert len(code) <= 40, f"the example grew to {len(code)} lines"
    _run(usage, _run(estimator))  # check_estimator raises AssertionError where the example breaks the contract


def test_the_suite_fails_the_example_once_it_reads_a_gap_as_motion():
    paper_rls = _run(_blocks()[0])["PaperRLS"]

    class Blind(paper_rls):
        def _gap_now(self):
            pass  # the gap forgotten: the next sample is read as motion from the last one

    with pytest.raises(AssertionError, match="check_a_gap_is_not_read_as_motion"):
        check_estimator(lambda: Blind(warm_start_samples=400))


def test_the_base_predicts_by_eq_1_to_3_from_theta():
    """The default ``predict_one`` (eq. 1-3 with the lines of ``theta_``, from the last output learned): on
    noise-free data of the paper's example 1 the example estimator predicts each next output."""
    namespace = _run(_blocks()[0])
    u = np.random.default_rng(5).uniform(-1.0, 1.0, 3000)
    x = simulate_backlash(u, BacklashParams(1.3, 0.5, 2.5, 0.7))
    est = namespace["PaperRLS"](origin="zero", warm_start_samples=400)
    est.learn_many(u[:2000], x[:2000])
    predicted = []
    for i in range(2000, 3000):
        predicted.append(est.predict_one(u[i]))
        est.learn_one(u[i], x[i])
    np.testing.assert_allclose(predicted, x[2000:], atol=1e-9)

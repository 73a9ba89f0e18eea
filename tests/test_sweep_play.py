"""One drive, one play (issue 27 item 5): the acceptance on the measured sweep, as ``bench/sweep_play.py`` prints it.

The sweep (``shared/data/davinci_tool_gearhead_backlash/sweep/``, ODbL v1.0: MRDLab
mis-tool-characterization, O'Neill, Stephens, Kowalewski, IEEE RA-L 3(4) 2018) is 50 runs of one
gearhead on one day. The bench runs all 50; this test runs 23 of them to keep the suite's time (about
10 s instead of 25): every reaction-torque setting at the slowest and the fastest frequency (0.1 and
0.5 Hz), and the 100 % runs of the three other frequencies, the runs where the load crosses the gap in
two steps.
"""

from __future__ import annotations

import importlib.util
import statistics
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "sweep_play.py"
SUBSET = [*range(0, 10), *range(40, 50), 19, 29, 39]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    spec = importlib.util.spec_from_file_location("sweep_play", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("sweep_play", bench)  # its dataclasses look their module up
    spec.loader.exec_module(bench)
    paths = bench.runs(SUBSET)
    if len(paths) != len(SUBSET):
        pytest.skip("the shared sweep is not beside the checkout")
    folder = tmp_path_factory.mktemp("sweep")
    return bench, [bench.measure(path, folder) for path in paths]


def test_every_run_reports_a_physical_play_or_why_not_and_the_std_covers_the_median(sweep):
    bench, results = sweep
    figures = bench.acceptance(results)
    assert figures["physical_or_reasoned"] is True
    assert figures["observable"] >= len(results) - 5 * len(results) / 50  # 45 of 50
    assert figures["coverage"] >= bench.MIN_COVERAGE
    assert figures["recursive_within_batch_std"] == f"{len(results)}/{len(results)}"
    assert figures["track_within_batch_std"] == f"{len(results)}/{len(results)}"
    assert {r.method for r in results} == {
        "kinematic"
    }  # the torque fits none of these runs' dwells (docs/load-aware.md)


def test_all_the_plays_lie_within_15_percent_of_their_median(sweep):
    """At 100 % reaction torque the load crosses the gap in two steps; the flank lines are fitted where
    the flanks are fully engaged (the partial crossings left out, estimators/full_engagement.py), so the
    100 % runs read the play the others do: before, 1.52-1.79 deg against 1.76-1.91 at 10-90 %."""
    bench, results = sweep
    assert bench.acceptance(results)["spread"] <= bench.MAX_SPREAD
    full = [r.play for r in results if "100pct" in r.name]
    rest = [r.play for r in results if "100pct" not in r.name]
    assert len(full) == 5 and all(p is not None for p in full)
    assert max(abs(p - statistics.median(rest)) for p in full) <= 0.1 * statistics.median(rest)

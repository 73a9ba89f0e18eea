"""A month of daily two-mass-rig logs under a changing load torque: trend and forecast against the truth.

The scenario is the one ``tests/test_history_load.py`` asserts (30 daily 20 s logs, the play
growing 0.002 deg a day, the external torque changing from day to day and every 5th day
preloaded, tracked with the torque column); this script prints both trend methods' figures for
it and for a constant load, so the numbers in ``docs/load-aware.md`` can be reproduced::

    python bench/wear_under_changing_load.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_history_load as scenario  # the test's scenario, not a copy of it


def main() -> None:
    folder = Path(tempfile.mkdtemp())
    loads = {"changing": lambda day: 1.0 if day % 5 == 4 else scenario.LOADS[day % 7], "constant": lambda day: 0.1}
    print("| load | method | trend deg/h (truth) | error | forecast h (truth) | error | not observable |")
    print("|---|---|---|---:|---|---:|---:|")
    for name, load in loads.items():
        for method in ("theil-sen", "kalman"):
            report, truth, last_play = scenario.track_month(folder / f"{name}-{method}.db", load, method)
            forecast_truth = (0.5 - last_play) / truth
            trend, forecast = report["trend_deg_per_hour"], report["forecast_hours_to_limit"]
            print(
                f"| {name} | {method} | {trend:.4f} ({truth:.4f}) | {trend / truth - 1:+.1%} | {forecast:.4f} "
                f"({forecast_truth:.4f}) "
                f"| {forecast / forecast_truth - 1:+.1%} | {report['n_not_observable']} |"
            )


if __name__ == "__main__":
    main()

"""Wear against the machine's hour meter: how close the trend, the machine hours and the date to the limit come.

Issue 28's done-when: on daily snapshot logs with an hour meter, the trend and the forecast in
machine hours within 10 % of the truth, the date within 10 % of the days remaining. Each case
writes a series of snapshot logs (:mod:`online_backlash.simulation.wear_logs`: a machine running 16 h a day,
the meter as a column, the play growing linearly with the machine's hours) into a temporary
folder, tracks it as ``online-backlash track LOG... --hours-column hours`` does, and reads
``history --json``'s figures:

* ``rig``: :func:`online_backlash.simulation.rig.simulate_rig` (eq. (1), quantised noisy encoders), 50 Hz,
  60 s snapshots, 40 days, play 12 -> 18 arcmin, limit 21 arcmin;
* ``two-mass``: :func:`online_backlash.simulation.two_mass_rig.simulate_two_mass` (a compliant drive with
  contact dynamics and a torque column, not the estimator's model), 500 Hz, 30 s snapshots,
  25 days, play 18 -> 24 arcmin, limit 27 arcmin, ``--memory-reversals 5``;

each on a ``regular`` schedule (a snapshot every day at 08:00) and an ``irregular`` one (about
30 % of the days without a snapshot, the others at any time from 06:00 to 18:00, a fifth of the
logs ten times longer; the same first and last log). Per case and seed: the errors of the wear
rate, of the machine hours to the limit and of the days to the limit, and whether the intervals
of the hours hold the truth; beside them the same trend as before issue 28 on the same estimates
(every estimate one point, all of equal weight) and the Kalman trend (``--trend kalman``) for comparison.

    python bench/wear_clock.py [--seeds 3]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import glob
import io
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from online_backlash.cli import main as cli
from online_backlash.history import HistoryStore
from online_backlash.history.report import estimate_column, observable_mask
from online_backlash.history.trend import summarise
from online_backlash.simulation.wear_logs import SnapshotPlan, daily, truth, write_snapshot_logs

COUNTS = ["--units", "counts", "--motor-cpr", "16384", "--load-cpr", "131072"]
#: simulator -> (plan options, days, limit in arcmin, extra track options)
CASES = {
    "rig": (dict(rate_hz=50.0, durations_s=(60.0,), play_start_deg=0.20, play_end_deg=0.30), 40, 21.0, []),
    "two-mass": (
        dict(simulator="two-mass", rate_hz=500.0, durations_s=(30.0,), play_start_deg=0.30, play_end_deg=0.40),
        25,
        27.0,
        ["--memory-reversals", "5"],
    ),
}


def plan_of(simulator: str, schedule: str, seed: int) -> SnapshotPlan:
    options, days, _, _ = CASES[simulator]
    options = {**options, "seed": 1000 * seed}
    if schedule == "regular":
        return daily(days, **options)
    rng = np.random.default_rng(seed)
    inner = [d + rng.uniform(6.0, 18.0) / 24.0 for d in range(1, days - 1) if rng.uniform() > 0.3]
    base = options.pop("durations_s")[0]
    durations = [base, *(10 * base if rng.uniform() < 0.2 else base for _ in inner), base]
    return SnapshotPlan(days=[8.0 / 24.0, *inner, days - 1 + 8.0 / 24.0], durations_s=durations, **options)


def history(db: str, method: str) -> dict:
    """``history --json --trend METHOD``."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli(["history", "--db", db, "--gearbox", "g", "--json", "--trend", method]) == 0
    return json.loads(out.getvalue())


def run_case(simulator: str, schedule: str, seed: int) -> dict:
    _, _, limit_arcmin, extra = CASES[simulator]
    plan = plan_of(simulator, schedule, seed)
    with tempfile.TemporaryDirectory() as folder:
        write_snapshot_logs(folder, plan)
        db = str(Path(folder) / "w.db")
        logs = sorted(glob.glob(str(Path(folder) / "*.csv.gz")))
        argv = [
            "track",
            *logs,
            "--ratio",
            "30",
            "--db",
            db,
            "--gearbox",
            "g",
            "--every",
            "10",
            "--quiet",
            *COUNTS,
            "--hours-column",
            "hours",
            "--limit-arcmin",
            str(limit_arcmin),
            *extra,
        ]
        started = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli(argv) == 0
        track_s = time.perf_counter() - started
        d, kalman = (history(db, method) for method in ("theil-sen", "kalman"))
        with HistoryStore(db) as store:
            est = store.estimates("g")
        names = ("time_unix_s", "operating_hours", "load_revolutions", "backlash_deg", "machine_hours")
        columns = {n: estimate_column(est, n) for n in names}
        before = summarise(**columns, limit_deg=limit_arcmin / 60.0, observable=observable_mask(est)).as_dict()
    last = d["estimates"][-1]
    true = truth(plan, limit_arcmin / 60.0, last["time_unix_s"])
    date = dt.datetime.fromisoformat(d["forecast_date_utc"]).timestamp()
    low, high = d["forecast_hours_to_limit_interval"]
    b_low, b_high = before["forecast_hours_to_limit_interval"]
    k_low, k_high = (math.inf if v is None else v for v in kalman["forecast_hours_to_limit_interval"])  # null: never
    return {
        "logs": len(plan.days),
        "points": d["trend_points"],
        "rate": d["trend_deg_per_hour"] / true["rate_deg_per_h"] - 1.0,
        "hours": d["forecast_hours_to_limit"] / true["hours_to_limit"] - 1.0,
        "days": (date - last["time_unix_s"]) / 86400.0 / true["days_to_limit"] - 1.0,
        "inside": low <= true["hours_to_limit"] <= high,
        "width": (high - low) / true["hours_to_limit"],
        "before_hours": before["forecast_hours_to_limit"] / true["hours_to_limit"] - 1.0,
        "before_inside": b_low <= true["hours_to_limit"] <= b_high,
        "before_width": (b_high - b_low) / true["hours_to_limit"],
        "kalman_hours": kalman["forecast_hours_to_limit"] / true["hours_to_limit"] - 1.0,
        "kalman_inside": k_low <= true["hours_to_limit"] <= k_high,
        "kalman_width": (k_high - k_low) / true["hours_to_limit"],
        "track_s": track_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=3)
    opts = parser.parse_args()
    print(
        "| simulator | schedule | seed | logs | trend points | wear rate | machine hours to the limit "
        "| days to the limit | truth in the hours' interval (width) | --trend kalman: hours, truth inside (width) "
        "| before issue 28: hours, truth inside (width) | track, s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    for simulator in CASES:
        for schedule in ("regular", "irregular"):
            for seed in range(1, opts.seeds + 1):
                r = run_case(simulator, schedule, seed)
                worst = max(worst, abs(r["rate"]), abs(r["hours"]), abs(r["days"]))
                print(
                    f"| {simulator} | {schedule} | {seed} | {r['logs']} | {r['points']} | {r['rate']:+.1%} "
                    f"| {r['hours']:+.1%} "
                    f"| {r['days']:+.1%} | {'yes' if r['inside'] else 'no'} ({r['width']:.0%}) "
                    f"| {r['kalman_hours']:+.1%}, {'yes' if r['kalman_inside'] else 'no'} ({r['kalman_width']:.0%}) "
                    f"| {r['before_hours']:+.1%}, {'yes' if r['before_inside'] else 'no'} ({r['before_width']:.0%}) "
                    f"| {r['track_s']:.1f} |",
                    flush=True,
                )
    print(f"\nlargest error of the rate, the machine hours and the days to the limit: {worst:.1%} (issue 28: < 10 %)")


if __name__ == "__main__":
    main()

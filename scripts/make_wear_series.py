"""Make the wear series bundled for ``online-backlash demo``: two months of daily snapshots against the hour meter.

A synthetic 30:1 gearbox (the rig of ``online_backlash.simulation.rig.simulate_rig``: rotation with reversals
every 2-6 s at 3 deg/s load side, 14-bit motor and 17-bit load encoders, 2 counts of noise, 50 Hz)
on a machine that runs 16 h a day. Once a day, at a time between 07:00 and 10:00 UTC, a 60 s
snapshot of its encoders is logged with the controller's hour meter (column ``hours``, 0.001 h
resolution), for 60 days from 2026-01-05. The play grows linearly with the machine's hours from
12 arcmin (0.20 deg) to 18 arcmin (0.30 deg, load side; 40 % on the left flank) over the series;
the limit, 21 arcmin, is reached about 30 days (about 470 machine hours) after the last snapshot.
Logs hold UNIX times, encoder counts and the meter. Run from the repository root:

    python scripts/make_wear_series.py

It writes ``src/online_backlash/data/wear/snapshot_YYYY-MM-DD_HHMMSS.csv.gz`` and ``series.json``
(the gearbox, the reader options, the hour-meter column and the true wear) deterministically
(seed 2026), after removing the series it replaces.
"""

import datetime as dt
import json
from pathlib import Path

import numpy as np

from online_backlash.simulation.wear_logs import SnapshotPlan, write_snapshot_logs

DAYS = 60
LIMIT_ARCMIN = 21.0
PLAN = SnapshotPlan(
    days=[
        d + np.round(h * 3600.0) / 86400.0 for d, h in enumerate(np.random.default_rng(2026).uniform(7.0, 10.0, DAYS))
    ],
    durations_s=(60.0,),
    start=dt.datetime(2026, 1, 5, tzinfo=dt.timezone.utc),
    hours_per_day=16.0,
    meter_start_h=5000.0,
    play_start_deg=0.20,
    play_end_deg=0.30,
    rate_hz=50.0,
    speed_deg_s=3.0,
    extra={"left_fraction": 0.4, "noise_counts": 2.0, "motor_bits": 14, "load_bits": 17},
)


def main() -> None:
    out = Path(__file__).resolve().parents[1] / "src" / "online_backlash" / "data" / "wear"
    out.mkdir(parents=True, exist_ok=True)
    for old in list(out.glob("*.csv.gz")) + list(out.glob("series.json")):
        old.unlink()
    logs = write_snapshot_logs(out, PLAN)
    limit_deg = LIMIT_ARCMIN / 60.0
    series = {
        "description": "synthetic 30:1 gearbox on a machine running 16 h a day: one 60 s snapshot a day for 60 days "
        "with the hour meter, play 12 -> 18 arcmin (load side) against the machine's hours; "
        "made by scripts/make_wear_series.py",
        "gearbox": "demo-30to1",
        "ratio": PLAN.ratio,
        "limit_arcmin": LIMIT_ARCMIN,
        "log_options": {"units": "counts", "motor_cpr": 2**14, "load_cpr": 2**17},
        "hours_column": "hours",
        "estimator_params": {},
        "every_s": 30.0,
        "hours_per_day": PLAN.hours_per_day,
        "true_rate_deg_per_hour": PLAN.rate_deg_per_h,
        "true_hours_at_limit": PLAN.limit_h(limit_deg),
        "true_limit_date": dt.datetime.fromtimestamp(PLAN.limit_unix_s(limit_deg), dt.timezone.utc).isoformat(),
        "logs": logs,
    }
    (out / "series.json").write_text(json.dumps(series, indent=2) + "\n")
    print(f"wrote {len(logs)} logs and series.json to {out}")


if __name__ == "__main__":
    main()

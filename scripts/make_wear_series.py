"""Make the multi-day wear series bundled for ``online-backlash demo``.

A synthetic 30:1 gearbox (the rig of ``online_backlash.rig.simulate_rig``: continuous rotation
with reversals every 2-6 s at about 30 deg/s load side, 14-bit motor and 17-bit load encoders,
2 counts of noise) logged once a day for 12 days, 25 s at 1 kHz each, starting 2026-11-02 08:00
UTC. Its play grows linearly with operating hours from 0.20 to 0.30 deg (load side; 40 % on the
left flank) over the 300 s of the series: wear accelerated so that a fortnight of short logs
shows it. The nominal limit is 21 arcmin (0.35 deg), which the play would reach after 450 s of
operation, i.e. on the 18th day at 25 s a day. Logs hold UNIX times and encoder counts. Run
from the repository root:

    python scripts/make_wear_series.py

It writes ``src/online_backlash/data/wear/day01.csv.gz`` ... ``day12.csv.gz`` and ``series.json``
(the gearbox, the reader options and the true wear), deterministically (seeds 2026 + day).
"""

import datetime as dt
import json
from pathlib import Path

from online_backlash.rig import simulate_rig

DAYS = 12
LOG_S = 25.0
START = dt.datetime(2026, 11, 2, 8, 0, tzinfo=dt.timezone.utc)
PLAY_START_DEG, PLAY_END_DEG = 0.20, 0.30
TOTAL_H = DAYS * LOG_S / 3600.0
RATE_DEG_PER_H = (PLAY_END_DEG - PLAY_START_DEG) / TOTAL_H
LIMIT_ARCMIN = 21.0
RIG = dict(ratio=30.0, left_fraction=0.4, noise_counts=2.0, motor_bits=14, load_bits=17)


def play_deg(hours: float):
    """Play as a function of the log's time (s), for a log that starts after ``hours`` of operation."""
    return lambda t: PLAY_START_DEG + RATE_DEG_PER_H * (hours + t / 3600.0)


def main() -> None:
    out = Path(__file__).resolve().parents[1] / "src" / "online_backlash" / "data" / "wear"
    out.mkdir(parents=True, exist_ok=True)
    logs = []
    for day in range(DAYS):
        start = START + dt.timedelta(days=day)
        rec = simulate_rig(duration_s=LOG_S, play_deg=play_deg(day * LOG_S / 3600.0), seed=2026 + day, **RIG)
        rec.time_s = rec.time_s + start.timestamp()
        name = f"day{day + 1:02d}.csv.gz"
        rec.write_csv(out / name, units="counts")
        logs.append({"file": name, "start": start.isoformat(), "play_deg_first": float(rec.play_deg[0]), "play_deg_last": float(rec.play_deg[-1])})
    series = {
        "description": "synthetic 30:1 gearbox wearing: play 0.20 -> 0.30 deg (load side) over 12 daily 25 s logs; "
        "made by scripts/make_wear_series.py",
        "gearbox": "demo-30to1",
        "ratio": RIG["ratio"],
        "limit_arcmin": LIMIT_ARCMIN,
        "log_options": {"units": "counts", "motor_cpr": 2 ** RIG["motor_bits"], "load_cpr": 2 ** RIG["load_bits"]},
        # the play grows 0.1 deg in 54 reversals, so the estimator's memory sets its lag behind the wear:
        # the trend came out 1.03 deg/h with the default 10 reversals, 1.15 with 5 (true: 1.20)
        "estimator_params": {"memory_reversals": 5.0},
        "every_s": 5.0,
        "true_rate_deg_per_hour": RATE_DEG_PER_H,
        "true_hours_at_limit": (LIMIT_ARCMIN / 60.0 - PLAY_START_DEG) / RATE_DEG_PER_H,
        "logs": logs,
    }
    (out / "series.json").write_text(json.dumps(series, indent=2) + "\n")
    print(f"wrote {DAYS} logs and series.json to {out}")


if __name__ == "__main__":
    main()

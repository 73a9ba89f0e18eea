"""``online-backlash demo``: the main job on data bundled with the package (no rig needed).

First one recording (estimate and characteristic plot), then two months of daily 60 s snapshots
of one gearbox wearing on a machine that runs 16 h a day, with its hour meter, replayed into a
temporary SQLite wear history: trend against machine hours, forecast in machine hours and as a
date, wear plot.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from importlib import resources
from pathlib import Path

from ..log_fit import fit_batch, fit_recursive, report_text
from ..plotting import plot_fit
from .history import describe_trend

#: The bundled log (made by scripts/make_demo_log.py): 30:1 gearbox, 0.50 deg play, encoder counts.
DEMO_LOG = "demo_rig_30to1.csv.gz"
DEMO_OPTIONS = {"units": "counts", "motor_cpr": 2**14, "load_cpr": 2**17}
DEMO_RATIO = 30.0


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the main job on a bundled recording (no rig needed)",
        description="Estimate the backlash of a bundled 30:1 gearbox recording (true play 0.50 deg) and plot the fit; "
        "then replay two months of daily snapshots of one gearbox wearing, with its machine's hour meter, into a "
        "temporary wear history and forecast in machine hours and as a date when its play crosses the limit.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--plot", default="backlash-demo.png", help="where to write the plot (PNG)")
    parser.add_argument(
        "--wear-plot", metavar="FILE.png", help="where to write the wear plot (default: wear-demo.png beside --plot)"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..replay import read_csv_arrays  # the readers load only when the demo runs, not for --help

    with resources.as_file(resources.files("online_backlash") / "data" / DEMO_LOG) as path:
        chunk = read_csv_arrays(path, **DEMO_OPTIONS)
        report, _ = fit_recursive([chunk], DEMO_RATIO, source=path.name)
        batch = fit_batch(chunk, DEMO_RATIO)
        print(f"bundled recording: 30:1 gearbox, true play 0.500 deg ({DEMO_LOG})")
        print(report_text(report, path.name))
        print(f"batch fit:      {batch[0].backlash_deg:.4f} deg (the paper's algorithm on the whole log; plotted)")
    plot_fit(chunk, DEMO_RATIO, args.plot, title="online-backlash demo: 30:1 gearbox", fitted=batch)
    print(f"plot:           {args.plot}")
    wear_demo(args.wear_plot or Path(args.plot).with_name("wear-demo.png"))
    return 0


def wear_demo(plot_path: str | Path) -> None:
    """Replay the bundled wear series into a temporary SQLite history; print trend and forecast; plot."""
    import datetime as dt

    from ..history import HistoryStore, bundled_wear_series, plot_wear, wear_report  # SQLAlchemy, scipy: only here
    from ..history.text import amount, rate
    from ..tracking import track_series

    series = bundled_wear_series()
    truth = series.manifest
    shift_s = series.shift_to_end_before(time.time())
    with tempfile.TemporaryDirectory() as folder, HistoryStore(Path(folder) / "wear.db", create=True) as store:
        track_series(series, store, shift_s=shift_s)
        report = wear_report(store, series.gearbox)
    logs = truth["logs"]
    print()
    print(
        f"wear history:   {len(series.files)} daily 60 s snapshots of gearbox {series.gearbox} on a machine running "
        f"{truth['hours_per_day']:g} h a day, each with its hour meter (true play {logs[0]['play_deg_first'] * 60:.1f} "
        f"-> {logs[-1]['play_deg_last'] * 60:.1f} arcmin), replayed into a temporary SQLite store: "
        f"{len(report.estimates)} estimates"
    )
    print(
        f"dates:          the series was recorded {logs[0]['start'][:10]} .. {logs[-1]['start'][:10]}; "
        f"the demo shifts it by {shift_s / 86400:.0f} days so that its last log is the latest one before now; "
        "dates are UTC on that shifted clock"
    )
    print("\n".join(describe_trend(report)))
    clock = report.summary.clock
    left = truth["true_hours_at_limit"] - (report.summary.last_x or 0.0)
    limit_date = dt.datetime.fromisoformat(truth["true_limit_date"]).timestamp() + shift_s
    on = dt.datetime.fromtimestamp(limit_date, dt.timezone.utc).date()
    print(
        f"true wear:      {rate(truth['true_rate_deg_per_hour'], clock)}; the limit is reached at "
        f"{amount(truth['true_hours_at_limit'], clock)} on the hour meter, {amount(left, clock)} after the last "
        f"estimate, on {on}"
    )
    plot_wear(report, plot_path)
    print(f"wear plot:      {plot_path}")

"""``online-backlash history --db DB --gearbox ID``: a gearbox's estimates, wear trend and forecast."""

from __future__ import annotations

import argparse
import csv
import math
import sys
from typing import TYPE_CHECKING

from ..errors import BacklashError, InvalidParameterError
from ..output_columns import ARCMIN_PER_DEG, HISTORY_CSV_COLUMNS
from ._options import add_max_age_option, add_play_level_options, add_store_option, nonempty_text
from ._output import check_plot_path, print_json

if TYPE_CHECKING:
    from ..history.report import WearReport


def add_db_options(parser: argparse.ArgumentParser, gearbox_required: bool = True) -> None:
    """``--db`` and ``--gearbox``, shared with ``track``."""
    add_store_option(parser)
    parser.add_argument(
        "--gearbox", type=nonempty_text, required=gearbox_required, metavar="ID", help="the gearbox's id in the store"
    )


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "history",
        help="show a gearbox's wear history, trend and forecast",
        description="Show the stored backlash estimates of one gearbox, the trend against operating hours "
        "(Theil-Sen or a Kalman local linear trend, with confidence and prediction bands), when it will cross the "
        "limit, and its alarm state (ok, warning, alarm, unknown); --check prints it as a Nagios/Icinga plugin line.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add_db_options(parser, gearbox_required=False)
    output = parser.add_mutually_exclusive_group()
    output.add_argument("--json", action="store_true", help="print one JSON object")
    output.add_argument("--csv", action="store_true", help="print the estimates as CSV")
    output.add_argument(
        "--check",
        action="store_true",
        help="print one line per gearbox in the Nagios/Icinga plugin format and exit 0/1/2/3 "
        "(OK/WARNING/CRITICAL/UNKNOWN; "
        "with --all the worst, in the order OK < WARNING < UNKNOWN < CRITICAL)",
    )
    parser.add_argument("--all", action="store_true", help="with --check: every gearbox in the store")
    add_play_level_options(
        parser,
        "backlash limit for the forecast; without it, the gearbox's stored limit",
        "warning level of the play; without it, the gearbox's stored one",
    )
    add_max_age_option(parser)
    parser.add_argument(
        "--trend",
        choices=("theil-sen", "kalman"),
        default="theil-sen",
        help="wear trend: Theil-Sen line, or a Kalman local linear trend (level and wear rate, RTS-smoothed, "
        "corrected for the estimator's lag); see docs/wear-trend.md",
    )
    parser.add_argument("--plot", metavar="FILE.png", help="also draw the wear plot into this file")
    parser.add_argument(
        "--confidence", type=float, default=0.95, help="confidence of the trend band and forecast interval"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here: SQLAlchemy, scipy.stats and matplotlib load only for this subcommand
    from ..history.plot import plot_wear
    from ..history.report import wear_report
    from ..history.store import HistoryStore

    if args.check:
        return run_check(args)
    if args.gearbox is None or args.all:
        raise InvalidParameterError("give --gearbox ID (--all only goes with --check)")
    check_plot_path(args.plot)
    with HistoryStore(args.db, read_only=True) as store:
        report = wear_report(store, args.gearbox, **report_options(args))
    if args.plot:
        plot_wear(report, args.plot)
    if args.json:
        print_json(report.as_dict())
    elif args.csv:
        write_csv(report)
    else:
        print(describe(report))
        if args.plot:
            print(f"wear plot: {args.plot}")
    return 0


def report_options(args: argparse.Namespace) -> dict:
    """The keyword arguments of ``wear_report`` given on the command line."""
    return {
        "limit_arcmin": args.limit_arcmin,
        "warn_arcmin": args.warn_arcmin,
        "confidence": args.confidence,
        "method": args.trend,
        "max_age_h": args.max_age_h,
    }


def run_check(args: argparse.Namespace) -> int:
    """``--check``: plugin lines for one gearbox or all; any error is one UNKNOWN line, exit 3."""
    from ..history.alarms import PLUGIN_STATUS, plugin_line, worst_state
    from ..history.report import wear_report
    from ..history.store import HistoryStore
    from ..history.text import wear_figures

    if (args.gearbox is None) == (not args.all):
        print("BACKLASH UNKNOWN - give --gearbox ID or --all with --check")
        return PLUGIN_STATUS["unknown"][1]
    try:
        with HistoryStore(args.db, read_only=True) as store:
            ids = store.gearbox_ids() if args.all else [args.gearbox]
            reports = [wear_report(store, gearbox_id, **report_options(args)) for gearbox_id in ids]
    except (BacklashError, OSError) as exc:
        print(f"BACKLASH UNKNOWN - error: {exc}")
        return PLUGIN_STATUS["unknown"][1]
    if not reports:
        print(f"BACKLASH UNKNOWN - no gearbox in {args.db}")
        return PLUGIN_STATUS["unknown"][1]
    for report in reports:
        print(plugin_line(report.gearbox.id, report.status, wear_figures(report).forecast_short))
    return PLUGIN_STATUS[worst_state([r.status.state for r in reports])][1]


def write_csv(report: WearReport) -> None:
    writer = csv.DictWriter(sys.stdout, fieldnames=HISTORY_CSV_COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(report.rows())


def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None or not math.isfinite(value) else format(value, fmt)


def describe(report: WearReport) -> str:
    """The text report: a table of estimates, then trend and forecast."""
    g = report.gearbox
    limit = "none stored" if g.limit_arcmin is None else f"{g.limit_arcmin:g} arcmin"
    warn = "" if g.warn_arcmin is None else f", warning level {g.warn_arcmin:g} arcmin"
    hidden = int((~report.observable).sum())
    counted = f", {hidden} with the play not observable (marked *, left out of the trend)" if hidden else ""
    lines = [f"gearbox {g.id}: ratio {g.ratio:g}, limit {limit}{warn}, {len(report.estimates)} estimates{counted}"]
    header = (
        f"{'time (UTC)':<20} {'machine h':>10} {'op. hours':>10} {'load rev':>10} {'reversals':>9} "
        f"{'backlash deg':>12} {'std deg':>9} {'arcmin':>8} {'std arcmin':>10}"
    )
    lines += [header, "-" * len(header)]
    for row, seen in zip(report.rows(), report.observable):
        lines.append(
            f"{row['time'][:19].replace('T', ' '):<20} {_num(row['machine_hours'], '10.2f'):>10} "
            f"{row['operating_hours']:>10.3f} {row['load_revolutions']:>10.1f} "
            f"{row['reversals']:>9d} {_num(row['backlash_deg'], '12.4f'):>12} "
            f"{_num(row['backlash_std_deg'], '9.4f'):>9} "
            f"{_num(row['backlash_arcmin'], '8.2f'):>8} "
            f"{_num(row['backlash_std_arcmin'], '10.2f'):>10}{'' if seen else ' *'}"
        )
    lines.append("")
    lines += describe_trend(report)
    st = report.status_dict()
    lines.append(f"state: {st['state']} ({st['state_reason']}; checked at {st['checked_at']} by the wall clock, UTC)")
    return "\n".join(lines)


def describe_trend(report: WearReport) -> list[str]:
    """Clock, trend, use and forecast lines (shared with ``demo``), in the words of
    :func:`~online_backlash.history.text.wear_figures`."""
    from ..history.clock import LOAD_REVOLUTIONS, OPERATING_HOURS
    from ..history.text import amount, rate, wear_figures

    f, s = wear_figures(report), report.summary
    lines = [f"clock: {f.clock}", f"trend: {f.trend}"]
    if s.trend is not None and s.last_x is not None:
        lines[-1] += f", now {float(s.trend.line(s.last_x)) * ARCMIN_PER_DEG:.2f} arcmin on the trend line"
    if s.per_revolution is not None and s.clock.key != "load_revolutions":
        lines.append(f"       {rate(s.per_revolution.slope, LOAD_REVOLUTIONS)}")
    hf = s.hours_forecast
    if s.clock.key == "load_revolutions" and s.per_hour is not None:  # the logs cover the running: their hours count
        lines.append(f"       {rate(s.per_hour.slope, OPERATING_HOURS)}")
        if hf is not None and math.isfinite(hf.to_limit) and hf.to_limit >= 0:
            interval = f"[{hf.to_limit_low:.3g}, {_num(hf.to_limit_high, '.3g')}]"
            lines.append(f"       limit in {amount(hf.to_limit, OPERATING_HOURS)} {interval}")
    if f.use:
        lines.append(f"use: {f.use}")
    lines.append(f"forecast: {f.forecast}")
    return lines

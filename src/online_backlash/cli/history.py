"""``online-backlash history --db DB --gearbox ID``: a gearbox's estimates, wear trend and forecast."""

from __future__ import annotations

import argparse
import csv
import math
import sys
from typing import TYPE_CHECKING

from ..errors import BacklashError, InvalidParameterError
from ..rows import HISTORY_CSV_COLUMNS
from ._common import check_plot_path, nonempty_text, print_json

if TYPE_CHECKING:
    from ..history.report import WearReport


def add_db_options(parser: argparse.ArgumentParser, gearbox_required: bool = True) -> None:
    """``--db`` and ``--gearbox``, shared with ``track``."""
    parser.add_argument("--db", required=True, help="history store: an SQLite file path or postgresql://user@host/dbname")
    parser.add_argument("--gearbox", type=nonempty_text, required=gearbox_required, metavar="ID", help="the gearbox's id in the store")


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
        help="print one line per gearbox in the Nagios/Icinga plugin format and exit 0/1/2/3 (OK/WARNING/CRITICAL/UNKNOWN; "
        "with --all the worst, in the order OK < WARNING < UNKNOWN < CRITICAL)",
    )
    parser.add_argument("--all", action="store_true", help="with --check: every gearbox in the store")
    parser.add_argument("--limit-arcmin", type=float, metavar="X", help="backlash limit for the forecast; without it, the gearbox's stored limit")
    parser.add_argument("--warn-arcmin", type=float, metavar="X", help="warning level of the play; without it, the gearbox's stored one")
    parser.add_argument(
        "--max-age-h",
        type=float,
        default=168.0,
        metavar="H",
        help="the state is UNKNOWN when the latest observable estimate is older than H calendar hours",
    )
    parser.add_argument(
        "--trend",
        choices=("theil-sen", "kalman"),
        default="theil-sen",
        help="wear trend: Theil-Sen line, or a Kalman local linear trend (level and wear rate, RTS-smoothed, "
        "corrected for the estimator's lag); see docs/wear-trend.md",
    )
    parser.add_argument("--plot", metavar="FILE.png", help="also draw the wear plot into this file")
    parser.add_argument("--confidence", type=float, default=0.95, help="confidence of the trend band and forecast interval")
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
        status = report.status_dict()
        print(plugin_line(report.gearbox.id, report.status, report.summary.as_dict()["forecast_hours_to_limit"], status["limit_exceeded_since"]))
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
    header = f"{'time (UTC)':<20} {'op. hours':>10} {'load rev':>10} {'reversals':>9} {'backlash deg':>12} {'std deg':>9} {'arcmin':>8} {'std arcmin':>10}"
    lines += [header, "-" * len(header)]
    for row, seen in zip(report.rows(), report.observable):
        lines.append(
            f"{row['time'][:19].replace('T', ' '):<20} {row['operating_hours']:>10.3f} {row['load_revolutions']:>10.1f} "
            f"{row['reversals']:>9d} {_num(row['backlash_deg'], '12.4f'):>12} {_num(row['backlash_std_deg'], '9.4f'):>9} "
            f"{_num(row['backlash_arcmin'], '8.2f'):>8} {_num(row['backlash_std_arcmin'], '10.2f'):>10}{'' if seen else ' *'}"
        )
    lines.append("")
    lines += describe_trend(report)
    st = report.status_dict()
    lines.append(f"state: {st['state']} ({st['state_reason']}; checked at {st['checked_at']} by the wall clock, UTC)")
    return "\n".join(lines)


def describe_trend(report: WearReport) -> list[str]:
    """Trend and forecast lines (shared with ``demo``)."""
    s = report.summary.as_dict()
    if s["trend_deg_per_hour"] is None:
        return ["trend: needs at least 3 estimates at different operating hours"]
    lo, hi = s["trend_deg_per_hour_interval"]
    conf = f"{s['trend_confidence']:.0%}"
    method = "Kalman local linear trend, lag-corrected" if s["trend_method"] == "kalman" else "Theil-Sen"
    lines = [
        f"trend: {s['trend_deg_per_hour']:+.4g} deg per operating hour [{lo:+.4g}, {hi:+.4g}] ({conf}, {method}), "
        f"now {s['trend_backlash_deg_now']:.4f} deg on the trend line",
    ]
    if s["trend_deg_per_revolution"] is not None:
        lines.append(f"       {s['trend_deg_per_revolution'] * 1000:+.4g} deg per 1000 load revolutions")
    if s["usage_hours_per_day"] is not None:
        lines.append(f"use: {s['usage_hours_per_day']:.3g} operating hours per day recently")
    if s["limit_deg"] is None:
        lines.append("forecast: no limit (give --limit-arcmin, or store one with track --limit-arcmin)")
        return lines
    h, (h_lo, h_hi) = s["forecast_hours_to_limit"], s["forecast_hours_to_limit_interval"]
    limit = f"limit {s['limit_arcmin']:g} arcmin ({s['limit_deg']:.4f} deg)"
    since = report.status_dict()["limit_exceeded_since"]
    if since is not None:
        lines.append(
            f"alarm: {limit} exceeded since {since} (the estimates' clock, UTC); "
            f"play now {report.status.play_arcmin:.1f} arcmin"
        )
        return lines
    if not math.isfinite(h):
        lines.append(f"forecast: {limit} not reached (the trend does not grow)")
        return lines
    interval = f"[{h_lo:.3g}, {_num(h_hi, '.3g')}]"
    if h < 0:
        lines.append(f"forecast: {limit} crossed by the trend line {-h:.3g} operating hours before the last estimate {interval}")
    else:
        lines.append(f"forecast: {limit} reached in {h:.3g} operating hours {interval} from the last estimate")
    if s["forecast_date"] is not None:
        d_lo, d_hi = s["forecast_date_interval"]
        clock = "on the estimates' clock" if h < 0 else "at the recent rate of use, counted from the last estimate's time"
        lines.append(f"          around {s['forecast_date']} [{d_lo}, {d_hi or 'never'}] (UTC) {clock}")
        today = report.status_dict()["checked_at"][:10]
        if h >= 0 and s["forecast_date"] < today:
            last = report.rows()[-1]["time"][:10]
            lines.append(f"          which is before today ({today}): the last estimate is from {last}; track newer logs")
    return lines

"""``online-backlash estimate LOG --ratio R``: fit the backlash of one recorded log."""

from __future__ import annotations

import argparse
import csv

from ..errors import InvalidParameterError
from ..fitting import TRACE_COLUMNS, describe, fit_batch, fit_recursive
from ..replay import CsvLog, read_csv_arrays
from ._common import add_log_options, add_ratio_option, parse_column_map, print_json


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "estimate",
        help="fit the backlash of a recorded log",
        description=(
            "Fit the backlash (Voros 2010) between the motor angle referred to the load side and the load angle "
            "of one log: recursively, streaming the log in chunks (default), or by the paper's batch algorithm "
            "on the whole log in memory."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("log", help="recorded log (.csv, .csv.gz)")
    add_ratio_option(parser)
    parser.add_argument("--method", choices=("recursive", "batch"), default="recursive", help="estimator")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    group = parser.add_argument_group("recursive method")
    group.add_argument("--trace", metavar="FILE.csv", help="write the estimate over time: " + ",".join(TRACE_COLUMNS))
    group.add_argument("--every", metavar="S", type=float, default=1.0, help="seconds of data between trace rows")
    group.add_argument("--memory-reversals", type=float, default=10.0, help="memory of the estimator, in reversals")
    group.add_argument("--memory-s", type=float, help="memory in seconds of motion (instead of / besides reversals)")
    group.add_argument("--sample-period", type=float, default=0.001, help="sampling period of the log, seconds")
    add_log_options(parser)
    parser.set_defaults(func=run)


def log_options(args: argparse.Namespace) -> dict:
    """Reader options from the log-format arguments."""
    return {
        "columns": parse_column_map(args.columns),
        "units": args.units,
        "motor_cpr": args.motor_cpr,
        "load_cpr": args.load_cpr,
        "skip_bad": args.skip_bad_rows,
    }


def run(args: argparse.Namespace) -> int:
    if args.method == "batch":
        if args.trace:
            raise InvalidParameterError("--trace needs --method recursive")
        report, _ = fit_batch(read_csv_arrays(args.log, **log_options(args)), args.ratio)
    else:
        params = {"memory_reversals": args.memory_reversals, "memory_s": args.memory_s, "sample_period_s": args.sample_period}
        with CsvLog(args.log, **log_options(args)) as log:
            if args.trace:
                with open(args.trace, "w", newline="") as f:
                    writer = csv.DictWriter(f, fieldnames=TRACE_COLUMNS)
                    writer.writeheader()
                    report, _ = fit_recursive(log.iter_chunks(), args.ratio, every_s=args.every, trace=writer.writerow, source=args.log, **params)
            else:
                report, _ = fit_recursive(log.iter_chunks(), args.ratio, source=args.log, **params)
    if args.json:
        print_json(report.as_dict())
    else:
        print(describe(report, args.log))
    return 0

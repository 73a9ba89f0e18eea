"""``online-backlash estimate LOG --ratio R``: fit the backlash of one recorded log."""

from __future__ import annotations

import argparse

from ..fitting import describe, fit_batch
from ..replay import read_csv_arrays
from ._common import add_log_options, add_ratio_option, parse_column_map, print_json


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "estimate",
        help="fit the backlash of a recorded log",
        description="Fit the backlash (Voros 2010) between the motor angle referred to the load side and the load angle of one log.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("log", help="recorded log (.csv, .csv.gz)")
    add_ratio_option(parser)
    parser.add_argument("--method", choices=("batch",), default="batch", help="estimator")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
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
    chunk = read_csv_arrays(args.log, **log_options(args))
    report, _ = fit_batch(chunk, args.ratio)
    if args.json:
        print_json(report.as_dict())
    else:
        print(describe(report, args.log))
    return 0

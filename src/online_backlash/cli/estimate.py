"""``online-backlash estimate LOG --ratio R``: fit the backlash of one recorded log."""

from __future__ import annotations

import argparse
import csv
import os
from collections.abc import Iterable
from typing import Any

from .._allocator import keep_freed_memory
from ..bridging import BRIDGE_S, JUMP_DEG, GapPolicy
from ..errors import InvalidParameterError
from ..fitting import BacklashReport, describe, fit_batch, fit_recursive
from ..pipeline import READ_AHEAD
from ..rows import TRACE_COLUMNS, EstimateRow
from ..stream import SampleChunk, SampleSource, read_all
from ._common import (
    LOG_FORMATS,
    add_can_decoding_options,
    add_log_options,
    add_ratio_option,
    can_decoding_options,
    check_plot_path,
    csv_dialect_options,
    files_written,
    nonnegative_float,
    parse_column_map,
    play_exit_code,
    positive_float,
    print_report,
    warn_if_implausible,
)


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
    parser.add_argument(
        "log", help=f"recorded log: {LOG_FORMATS}; or a listen --raw-log folder")
    add_ratio_option(parser)
    parser.add_argument("--method", choices=("recursive", "batch"), default="recursive", help="estimator")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--rated-torque", metavar="NM", type=positive_float,
        help="rated torque of the gearbox, N m: with a torque column, lost motion is taken at +-3 %% of it (else at the torque dead band)",
    )
    parser.add_argument(
        "--plot", metavar="FILE.png",
        help="write a plot of a batch fit of the whole log (read into memory): with a torque column the data-sheet "
        "hysteresis curve (torsion angle vs torque), else the backlash characteristic",
    )
    group = parser.add_argument_group("recursive method")
    group.add_argument("--trace", metavar="FILE.csv", help="write the estimate over time: " + ",".join(TRACE_COLUMNS))
    group.add_argument("--every", metavar="S", type=positive_float, default=1.0, help="seconds of data between trace rows")
    group.add_argument(
        "--memory-reversals", type=positive_float, default=10.0, help="memory of the estimator, in reversals"
    )
    group.add_argument(
        "--memory-s", type=positive_float, help="memory in seconds of motion (instead of / besides reversals)"
    )
    group.add_argument("--sample-period", type=positive_float, default=0.001, help="sampling period of the log, s")
    group.add_argument(
        "--bridge-s", type=nonnegative_float, default=BRIDGE_S,
        help="longest gap (seconds) the estimator is carried across, keeping its state; 0: every gap restarts it",
    )
    group.add_argument(
        "--jump-deg", type=nonnegative_float, default=JUMP_DEG,
        help="a step of either angle (deg, load side) larger than this across a gap is a jump in the data and restarts",
    )
    parser.add_argument(
        "--period", type=positive_float, metavar="S",
        help="nominal sample period for gap detection (CSV, CAN log, serial capture), as given to listen/track; learnt if not given. "
        "With a frame counter (CAN, serial, CANopen), sample times are then first time + counter periods x S, not the jittery timestamps",
    )
    add_log_options(parser)
    add_can_decoding_options(parser, required=False)
    parser.add_argument("--serial-format", choices=("ascii", "binary"), help="frame format of a serial capture (.serial)")
    parser.add_argument("--realtime", action="store_true", help="replay a CAN log or serial capture at its recorded pace")
    parser.set_defaults(func=run)


def log_options(args: argparse.Namespace) -> dict:
    """Reader options from the log-format arguments (by the log's suffix)."""
    from ..replay import log_suffix  # the readers (python-can, asammdf) load only when a log is read, not for --help
    from ..replay.csv import CSV_SUFFIXES
    from ..replay.measurement import is_measurement_log

    suffix = log_suffix(args.log)
    period = getattr(args, "period", None)
    timing = {} if period is None else {"period_s": period}  # measurement files take their time base from the file
    if suffix == ".serial":
        return {
            "serial_format": args.serial_format, "motor_cpr": args.motor_cpr, "load_cpr": args.load_cpr,
            "skip_bad": args.skip_bad_rows, "realtime": getattr(args, "realtime", False), **timing,
        }
    # a CAN log (or an unknown suffix, which open_log reports)
    if suffix not in CSV_SUFFIXES and not is_measurement_log(args.log):
        counts = {k: None if v is None else int(v) for k, v in (("motor_cpr", args.motor_cpr), ("load_cpr", args.load_cpr))}
        return {
            **can_decoding_options(args), **counts, "skip_bad": args.skip_bad_rows, "realtime": getattr(args, "realtime", False), **timing,
        }
    return {
        "columns": parse_column_map(args.columns),
        "units": args.units,
        "motor_cpr": args.motor_cpr,
        "load_cpr": args.load_cpr,
        "skip_bad": args.skip_bad_rows,
        **(timing if suffix in CSV_SUFFIXES else {}),
        **(csv_dialect_options(args) if suffix in CSV_SUFFIXES else {}),
    }


def read_counted(args: argparse.Namespace) -> tuple[SampleChunk, SampleSource]:
    """The whole log of ``args.log`` in memory (for batch fits) and its closed source, whose ``counters`` are final."""
    from ..replay import open_log

    source = open_log(args.log, **log_options(args))
    return read_all(source, args.log), source


def run(args: argparse.Namespace) -> int:
    from ..replay import open_log

    keep_freed_memory()  # a one-shot process: its large arrays reuse the memory freed by the last ones
    check_plot_path(args.plot)
    fitted = None
    if args.method == "batch":
        if args.trace:
            raise InvalidParameterError("--trace needs --method recursive")
        chunk, source = read_counted(args)
        fitted = fit_batch(chunk, args.ratio, rated_torque_Nm=args.rated_torque)
        report = fitted[0]
    else:
        params = {
            "memory_reversals": args.memory_reversals, "memory_s": args.memory_s, "sample_period_s": args.sample_period,
            "gap_policy": GapPolicy(args.bridge_s, args.jump_deg), "rated_torque_Nm": args.rated_torque,
        }
        with open_log(args.log, **log_options(args)) as source:
            if args.trace:
                report = write_trace(args.trace, source.iter_chunks(), args.ratio, args.every, args.log, **params)
            else:
                report, _ = fit_recursive(source.iter_chunks(), args.ratio, source=args.log, ahead=READ_AHEAD, **params)
    report.add_counters(source.counters.as_dict())
    if args.plot:
        from ..plotting import plot_fit  # matplotlib: only for a plot

        whole = chunk if args.method == "batch" else read_counted(args)[0]
        title = os.path.basename(args.log)
        drawn = plot_fit(whole, args.ratio, args.plot, rated_torque_Nm=args.rated_torque, title=title, fitted=fitted)
        if fitted is None:  # the data-sheet figures of the curve drawn, not a second set from the recursive fit
            report.take_datasheet(drawn)
    print_report(report.as_dict() if args.json else describe(report, args.log), files_written(args))
    warn_if_implausible(report.plausibility(args.ratio), args.log)
    return play_exit_code(report.backlash_deg, args.log, report.no_play_reason())


def write_trace(
    path: str | os.PathLike[str], chunks: Iterable[SampleChunk], ratio: float, every_s: float, source: str, **params: Any
) -> BacklashReport:
    """Run the recursive fit (the pipeline) and write its rows to ``path`` as CSV (columns ``TRACE_COLUMNS``)."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=TRACE_COLUMNS)
        writer.writeheader()

        def write(row: EstimateRow) -> None:
            writer.writerow(row.trace())

        report, _ = fit_recursive(chunks, ratio, every_s=every_s, trace=write, source=source, ahead=READ_AHEAD, **params)
    return report

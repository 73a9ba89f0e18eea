"""``online-backlash estimate LOG --ratio R``: fit the backlash of one recorded log."""

from __future__ import annotations

import argparse
import csv
import os
from collections.abc import Iterable
from typing import Any

from .._allocator import keep_freed_memory
from ..errors import InvalidParameterError
from ..gap_policy import BRIDGE_S, JUMP_DEG, GapPolicy
from ..log_fit import BacklashReport, fit_batch, fit_recursive, report_text
from ..output_columns import TRACE_COLUMNS, EstimateRow
from ..pipeline import READ_AHEAD
from ..stream import SampleChunk, SampleSource, read_all
from ._options import (
    add_can_decoding_options,
    add_estimator_options,
    add_log_options,
    add_period_option,
    add_play_method_option,
    add_ratio_option,
    add_serial_format_option,
    log_formats,
    nonnegative_float,
    positive_float,
    reader_options,
)
from ._output import check_plot_path, files_written, play_exit_code, print_report, warn_if_implausible


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
    parser.add_argument("log", help=f"recorded log: {log_formats()}; or a listen --raw-log folder")
    add_ratio_option(parser)
    parser.add_argument("--method", choices=("recursive", "batch"), default="recursive", help="estimator")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_play_method_option(parser)
    parser.add_argument(
        "--rated-torque",
        metavar="NM",
        type=positive_float,
        help="rated torque of the gearbox, N m: with a torque column, lost motion is taken at +-3 %% of it (else at "
        "the torque dead band)",
    )
    parser.add_argument(
        "--stiffness-torques",
        metavar="T1,T2",
        type=_segment_torques,
        help="with a torque column and --method batch: the data sheet's segment torques, N m: the torsional stiffness "
        "in three segments (K1 up to T1, K2 up to T2, K3 above; the segments the torque covers are fitted)",
    )
    parser.add_argument(
        "--plot",
        metavar="FILE.png",
        help="write a plot of a batch fit of the whole log (read into memory): with a torque column the data-sheet "
        "hysteresis curve (torsion angle vs torque), else the backlash characteristic",
    )
    group = parser.add_argument_group("recursive method")
    group.add_argument("--trace", metavar="FILE.csv", help="write the estimate over time: " + ",".join(TRACE_COLUMNS))
    group.add_argument(
        "--every", metavar="S", type=positive_float, default=1.0, help="seconds of data between trace rows"
    )
    add_estimator_options(group)
    group.add_argument(
        "--bridge-s",
        type=nonnegative_float,
        default=BRIDGE_S,
        help="longest gap (seconds) the estimator is carried across, keeping its state; 0: every gap restarts it",
    )
    group.add_argument(
        "--jump-deg",
        type=nonnegative_float,
        default=JUMP_DEG,
        help="a step of either angle (deg, load side) larger than this across a gap is a jump in the data and restarts",
    )
    add_period_option(parser)
    add_log_options(parser)
    add_can_decoding_options(parser, required=False)
    add_serial_format_option(parser)
    parser.add_argument(
        "--realtime", action="store_true", help="replay a CAN log or serial capture at its recorded pace"
    )
    parser.set_defaults(func=run)


def _segment_torques(text: str) -> tuple[float, float]:
    """argparse type of ``--stiffness-torques T1,T2`` (N m, 0 < T1 < T2)."""
    from ..load_aware.segments import check_knots

    try:
        return check_knots(text.split(","))
    except InvalidParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def log_options(args: argparse.Namespace) -> dict:
    """Reader options from the log-format arguments: those the log's format takes (``replay.FORMATS``); none for a
    log of no known format (opening it says so)."""
    from ..replay.registry import find_format  # the readers (python-can, asammdf) load only when a log is read

    log_format = find_format(args.log)
    if log_format is None:
        return {}
    return log_format.reader_kwargs(reader_options(args, log_format.options))


def read_counted(args: argparse.Namespace) -> tuple[SampleChunk, SampleSource]:
    """The whole log of ``args.log`` in memory (for batch fits) and its closed source, whose ``counters`` are final."""
    from ..replay import open_log

    source = open_log(args.log, **log_options(args))
    return read_all(source, args.log), source


def no_torque_reason(log: str | None, args: argparse.Namespace) -> str:
    """Why a log has no torque path: no torque column, or torque-like columns the column map leaves out
    (their names; read from the log's first block, only for logs of columns or channels)."""
    from ..load_aware.choice import NO_TORQUE
    from ..replay import open_log

    if log is None or log_options(argparse.Namespace(**{**vars(args), "log": log})).get("columns") is None:
        return NO_TORQUE
    with open_log(log, **log_options(argparse.Namespace(**{**vars(args), "log": log}))) as source:
        next(iter(source.iter_chunks()), None)
        unused = getattr(source, "unused_torque_columns", ())
    if not unused:
        return NO_TORQUE
    return f"no torque column mapped ({', '.join(unused)} present but not used: map one with --columns torque=NAME)"


def run(args: argparse.Namespace) -> int:
    from ..replay import open_log

    keep_freed_memory()  # a one-shot process: its large arrays reuse the memory freed by the last ones
    check_plot_path(args.plot)
    fitted = None
    choice = {"play_method": args.play_method, "no_torque_why": no_torque_reason(args.log, args)}
    if args.method == "batch":
        if args.trace:
            raise InvalidParameterError("--trace needs --method recursive")
        chunk, source = read_counted(args)
        fitted = fit_batch(
            chunk, args.ratio, rated_torque_Nm=args.rated_torque, stiffness_torques_Nm=args.stiffness_torques, **choice
        )
        report = fitted[0]
    else:
        if args.stiffness_torques is not None:
            raise InvalidParameterError(
                "--stiffness-torques needs --method batch: the three segments are fitted on the whole curve"
            )
        params = {
            "memory_reversals": args.memory_reversals,
            "memory_s": args.memory_s,
            "sample_period_s": args.sample_period,
            "gap_policy": GapPolicy(args.bridge_s, args.jump_deg),
            "rated_torque_Nm": args.rated_torque,
            **choice,
        }
        with open_log(args.log, **log_options(args)) as source:
            if args.trace:
                report = write_trace(args.trace, source.iter_chunks(), args.ratio, args.every, args.log, **params)
            else:
                report, _ = fit_recursive(source.iter_chunks(), args.ratio, source=args.log, ahead=READ_AHEAD, **params)
    report.add_counters(source.counters.as_dict())
    report.extra["unused_torque_columns"] = list(getattr(source, "unused_torque_columns", ()))
    if args.plot:
        from ..plotting import plot_fit  # matplotlib: only for a plot

        whole = chunk if args.method == "batch" else read_counted(args)[0]
        title = os.path.basename(args.log)
        drawn = plot_fit(
            whole, args.ratio, args.plot, rated_torque_Nm=args.rated_torque, title=title, fitted=fitted, **choice
        )
        if fitted is None:  # the data-sheet figures of the curve drawn, not a second set from the recursive fit
            report.take_datasheet(drawn)
    print_report(report.as_dict() if args.json else report_text(report, args.log), files_written(args))
    warn_if_implausible(report.plausibility(args.ratio), args.log)
    return play_exit_code(report.backlash_deg, args.log, report.no_play_reason())


def write_trace(
    path: str | os.PathLike[str],
    chunks: Iterable[SampleChunk],
    ratio: float,
    every_s: float,
    source: str,
    **params: Any,
) -> BacklashReport:
    """Run the recursive fit (the pipeline) and write its rows to ``path`` as CSV (columns ``TRACE_COLUMNS``)."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=TRACE_COLUMNS)
        writer.writeheader()

        def write(row: EstimateRow) -> None:
            writer.writerow(row.trace())

        report, _ = fit_recursive(
            chunks, ratio, every_s=every_s, trace=write, source=source, ahead=READ_AHEAD, **params
        )
    return report

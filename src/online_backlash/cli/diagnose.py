"""``online-backlash diagnose LOG --ratio R``: trace what the backlash model lacks, add it, report before/after."""

from __future__ import annotations

import argparse

from .._allocator import keep_freed_memory
from ..gap_policy import GapTally
from ..log_fit import plausibility
from ..output_columns import describe_counts, source_counts
from ._options import (
    add_can_decoding_options,
    add_log_options,
    add_ratio_option,
    add_serial_format_option,
    count_type,
    log_formats,
    positive_float,
)
from ._output import check_plot_path, files_written, play_exit_code, print_report, warn_if_implausible
from .estimate import read_counted, write_trace


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "diagnose",
        help="find effects the backlash model lacks in a recorded log and close the loop",
        description=(
            "Fit the backlash, test the residual for transmission error, delay, compliance and drift "
            "(and unexplained structure), add what is significant, refit jointly, and report the error "
            "before and after."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("log", help=f"recorded log: {log_formats()}")
    add_ratio_option(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--plot", metavar="FILE.png", help="write the residual before/after plot")
    parser.add_argument("--report", metavar="FILE.md", help="write a Markdown report")
    parser.add_argument("--max-terms", type=count_type, default=6, help="most terms (named or generic) to add")
    parser.add_argument(
        "--floor-ratio",
        type=positive_float,
        metavar="R",
        help="stop adding terms once the residual RMS is within R times the noise floor (the loop's default: 1.25; "
        "a larger R stops sooner, e.g. 1.5)",
    )
    parser.add_argument(
        "--screen-cycles",
        type=count_type,
        metavar="N",
        help="on a record of at least 3N reversal cycles and 300,000 samples, score and refit the candidates on N "
        "cycles "
        "spread over it (more if N hold fewer than 100,000 samples), then configure and fit the terms chosen on every "
        "sample "
        "(the loop's default: 10; 0: every cycle, slower on long logs)",
    )
    parser.add_argument(
        "--trace",
        metavar="FILE.csv",
        help="also track the backlash over the log with the named effects found (recursive estimator) and write "
        "the estimate over time, as estimate --trace does",
    )
    parser.add_argument(
        "--every", metavar="S", type=positive_float, default=1.0, help="seconds of data between trace rows"
    )
    add_log_options(parser)
    add_can_decoding_options(parser, required=False)
    add_serial_format_option(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    keep_freed_memory()  # a one-shot process: its large arrays reuse the memory freed by the last ones
    check_plot_path(args.plot)
    chunk, source = read_counted(args)  # first: a file that cannot be read fails before the diagnostics load
    # imported here: the diagnostics (scipy) load only for this subcommand, not for every CLI start
    from ..diagnostics.loop import diagnose
    from ..diagnostics.plot import plot_diagnosis
    from ..diagnostics.report import markdown_report

    counts = {**source_counts(source.counters.as_dict()), **GapTally.of_chunk(chunk).values()}
    options = {} if args.floor_ratio is None else {"floor_ratio": args.floor_ratio}
    if args.screen_cycles is not None:
        options["screen_cycles"] = args.screen_cycles
    result = diagnose(chunk, args.ratio, max_terms=args.max_terms, **options)
    if args.trace:
        write_trace(args.trace, [chunk], args.ratio, args.every, args.log, effects=result.effects)
    if args.plot:
        plot_diagnosis(result, args.plot)
    text = markdown_report(result, args.log, plot=args.plot) if args.report or not args.json else ""
    if args.report:
        with open(args.report, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    source_line = f"\nsource: {describe_counts(counts)}" if describe_counts(counts) else ""
    print_report({**result.as_dict(), **counts} if args.json else text + source_line, files_written(args))
    base = result.base
    warn_if_implausible(plausibility(base.m_left_, base.m_right_, base.backlash_, args.ratio), args.log)
    return play_exit_code(result.final.params.play, args.log)

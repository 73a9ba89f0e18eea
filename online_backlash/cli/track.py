"""``online-backlash track LOG --ratio R --db DB --gearbox ID``: add logs to a gearbox's wear history."""

from __future__ import annotations

import argparse
import datetime as dt
import sys

from tqdm import tqdm

from ..errors import InvalidParameterError
from ..history.store import HistoryStore
from ..history.track import GearboxTracker, TrackResult
from ._common import add_log_options, add_ratio_option, print_json
from .estimate import log_options
from .history import add_db_options


def _unix_time(text: str) -> float:
    """ISO 8601 date-time (UTC unless it names a zone) -> UNIX seconds."""
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an ISO 8601 time like 2026-11-22T08:00:00, got {text!r}") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.timezone.utc)
    return when.timestamp()


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "track",
        help="feed logs into a gearbox's wear history",
        description="Feed recorded logs through the recursive estimator of one gearbox and append an estimate "
        "every S seconds of data to the history store. Interrupted runs resume where their last checkpoint "
        "was; a log already imported adds nothing.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("logs", nargs="+", metavar="LOG", help="recorded logs (.csv, .csv.gz), in the order they were recorded")
    add_ratio_option(parser)
    add_db_options(parser)
    parser.add_argument("--every", type=float, default=60.0, metavar="S", help="seconds of data between estimates")
    parser.add_argument("--limit-arcmin", type=float, metavar="X", help="store this backlash limit with the gearbox")
    parser.add_argument(
        "--start",
        type=_unix_time,
        metavar="TIME",
        help="calendar time of the log's first sample (ISO 8601, UTC unless given); default: the time column "
        "if it holds UNIX times, else the file's modification time",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print one JSON object per log")
    add_log_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.start is not None and len(args.logs) > 1:
        raise InvalidParameterError(f"--start gives the start of one log; {len(args.logs)} logs were given")
    options = log_options(args)
    show_progress = not args.quiet and sys.stderr.isatty()
    with HistoryStore(args.db, create=True) as store:
        tracker = GearboxTracker(store, args.gearbox, args.ratio, every_s=args.every, limit_arcmin=args.limit_arcmin)
        for path in args.logs:
            with tqdm(desc=path, unit=" samples", unit_scale=True, disable=not show_progress, leave=False) as bar:

                def progress(samples: int, backlash_deg: float | None) -> None:
                    bar.update(samples - bar.n)
                    if backlash_deg is not None:
                        bar.set_postfix_str(f"backlash {backlash_deg:.4f} deg")

                result = tracker.track_log(path, options, start_unix_s=args.start, progress=progress)
            report(result, args.json)
    return 0


def report(result: TrackResult, as_json: bool) -> None:
    if as_json:
        print_json(vars(result))
        return
    where = f"{result.gearbox_id}: {result.source}"
    if result.already_imported:
        print(f"{where}: already imported (run {result.run_id}); nothing added")
        return
    resumed = f", resumed after {result.resumed_from} samples" if result.resumed_from else ""
    line = f"{where}: {result.samples_fed} samples{resumed}, {result.estimates_added} estimates added"
    last = result.last_estimate
    if last is not None:
        std = last["backlash_std_deg"]
        line += (
            f"; backlash {last['backlash_deg']:.4f} deg (std {std:.4f}) after {last['operating_hours']:.3f} operating hours"
        )
    print(line)

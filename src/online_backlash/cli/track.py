"""``online-backlash track LOG --ratio R --db DB --gearbox ID``: add logs to a gearbox's wear history.

With ``--listen can|serial`` and the source options of ``listen`` it tracks a live rig instead,
until ``--duration`` or Ctrl-C; the raw capture is written first, so it can be tracked again
as a log (into another gearbox id) with the same estimates.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from typing import TYPE_CHECKING, Any

from .._allocator import keep_freed_memory
from ..clocks import TIME_UNITS as TIME_UNIT_NAMES
from ..errors import BacklashError, InvalidParameterError
from ..fleet import GearboxJob, GearboxOutcome
from ..output_columns import describe_counts
from ._live import ctrl_c_ends_the_run, open_can_source, open_serial_source
from ._mqtt import add_mqtt_option, history_figures, mqtt_publisher, mqtt_summary_line, mqtt_tls
from ._options import (
    add_can_bus_options,
    add_can_decoding_options,
    add_estimator_options,
    add_live_run_options,
    add_log_options,
    add_period_option,
    add_play_level_options,
    add_play_method_option,
    add_ratio_option,
    add_serial_format_option,
    add_serial_port_options,
    log_formats,
    positive_float,
)
from ._output import print_json
from .estimate import log_options, no_torque_reason
from .history import add_db_options

if TYPE_CHECKING:
    from ..clocks import ClockOptions
    from ..history.store import HistoryStore
    from ..hour_meter import MachineUsage
    from ..tracking import GearboxTracker, ProgressCallback, RowCallback, TrackResult

#: The groups of ``track``'s options that are the command's, not one gearbox's (:func:`track_command_line_options`).
LIVE_GROUP = "live, instead of logs (the options of listen)"
FLEET_GROUP = "fleet, instead of one gearbox (see docs/fleet.md)"
#: The command's other options: the store and the output (``func``: argparse's handler).
COMMAND_OPTIONS = frozenset({"db", "json", "quiet", "debug", "func"})


def _hours(text: str) -> float:
    """argparse type of an hour-meter reading: finite, >= 0 hours."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (value >= 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected an hour-meter reading in hours (a number >= 0), got {text!r}")
    return value


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
    parser.add_argument(
        "logs",
        nargs="*",
        metavar="LOG",
        help="recorded logs (tracked in the order of their first samples' time), or listen --raw-log folders: "
        + log_formats(),
    )
    add_ratio_option(parser, required=False)
    add_db_options(parser, gearbox_required=False)
    parser.add_argument(
        "--every", type=positive_float, default=60.0, metavar="S", help="seconds of data between estimates"
    )
    add_play_level_options(
        parser,
        "store this backlash limit with the gearbox",
        "store this warning level of the play with the gearbox (not above the limit)",
    )
    clocks = parser.add_argument_group(
        "clocks: where a log lies in time and in the machine's use (see docs/wear-trend.md)"
    )
    clocks.add_argument(
        "--start",
        type=_unix_time,
        metavar="TIME",
        help="calendar time of the log's first sample (ISO 8601, UTC unless given); default: --start-from-name, the "
        "time column if it holds UNIX times, the file's own start time (MDF4 header, TDMS wf_start_time, Parquet "
        "timestamps), else the file's modification time",
    )
    clocks.add_argument(
        "--start-from-name",
        metavar="PATTERN",
        help="take each log's start from its file name, a strftime pattern found in it, e.g. "
        "'%%Y-%%m-%%d_%%H%%M%%S' for gb7_2026-11-02_080000.csv (UTC unless it has %%z)",
    )
    clocks.add_argument(
        "--time-unit",
        choices=tuple(TIME_UNIT_NAMES),
        help="unit of the log's time column; default: seconds, or ms/us when it steps by more than 0.2 from sample "
        "to sample (said in a warning)",
    )
    clocks.add_argument(
        "--operating-hours",
        type=_hours,
        metavar="H",
        help="the machine's hour meter at the log's first sample, hours (one log; per log in a fleet manifest): "
        "the wear trend and forecast run on machine hours",
    )
    clocks.add_argument(
        "--hours-column",
        metavar="NAME",
        help="the column (CSV, MDF4, TDMS, Parquet) or DBC signal that records the machine's hour meter with the "
        "angles",
    )
    clocks.add_argument(
        "--hours-unit",
        default="h",
        metavar="UNIT",
        help="unit of --hours-column: h, min, s, or hours per count (a cycle counter: its cycle time in hours)",
    )
    add_estimator_options(parser, new_gearbox=True)
    add_play_method_option(parser, default=None, new="a new gearbox's ")
    parser.add_argument(
        "--diagnose",
        action="store_true",
        help="for a new gearbox: run diagnose on the first log and track the named effects it finds with the backlash "
        "(a gearbox already tracked keeps the effects stored in its checkpoint)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print one JSON object per log")
    add_log_options(parser)
    add_can_decoding_options(parser, required=False)
    add_serial_format_option(parser)
    live = parser.add_argument_group(LIVE_GROUP)
    live.add_argument(
        "--listen",
        choices=("can", "serial"),
        help="track live from a CAN bus or a serial port until --duration or Ctrl-C",
    )
    add_can_bus_options(live, required=False)
    add_serial_port_options(live, required=False)
    add_live_run_options(live, raw_log_required=False)
    add_period_option(live)
    add_mqtt_option(live)
    fleet = parser.add_argument_group(FLEET_GROUP)
    fleet.add_argument(
        "--manifest",
        metavar="TOML",
        help="track every gearbox of this fleet manifest ([defaults], [[gearbox]] tables of track options)",
    )
    fleet.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="with --manifest: Dask worker processes on this machine (default: its cores); 0: gearboxes one by one "
        "here",
    )
    fleet.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="with --manifest: run on this Dask scheduler's workers instead of local ones",
    )
    parser.set_defaults(func=run)


def check_track_args(args: argparse.Namespace) -> None:
    """The checks of one gearbox's options that argparse cannot make (InvalidParameterError)."""
    from ..history.alarms import check_alarm_levels

    if args.gearbox is None or args.ratio is None:
        raise InvalidParameterError("give --gearbox ID and --ratio R (or --manifest for a fleet)")
    if args.listen is None and not args.logs:
        raise InvalidParameterError("give the logs to track, or --listen can|serial to track live")
    if args.listen is not None and (args.logs or args.raw_log is None):
        raise InvalidParameterError("--listen tracks live: give --raw-log DIR and no logs")
    if args.mqtt is not None and args.listen is None:
        raise InvalidParameterError("--mqtt publishes live estimates: use it with --listen")
    check_one_log_options(args, len(args.logs), "per log: a fleet manifest")
    if args.start is not None and args.start_from_name is not None:
        raise InvalidParameterError("give the log's start as --start or --start-from-name, not both")
    log_only = ("operating_hours", "hours_column", "start_from_name")
    if args.listen is not None and any(getattr(args, k) is not None for k in log_only):
        raise InvalidParameterError("--operating-hours, --hours-column, --start-from-name are for logs, not --listen")
    usage_of(args, None)  # the hour meter's options, checked
    clock_of(args, None)
    if args.diagnose and args.listen is not None:
        raise InvalidParameterError(
            "--diagnose diagnoses the first log: track a log first, then --listen continues with its effects"
        )
    check_alarm_levels(args.warn_arcmin, args.limit_arcmin)


def run(args: argparse.Namespace) -> int:
    if args.manifest is not None:
        from ._fleet import run_manifest

        return run_manifest(
            args, track_gearbox, parse_track_argv, track_defaults(), track_command_line_options(), report
        )
    if args.workers is not None or args.scheduler is not None:
        raise InvalidParameterError("--workers and --scheduler run a fleet: give them with --manifest")
    check_track_args(args)
    # imported here: SQLAlchemy loads only for this subcommand
    from ..history.store import HistoryStore

    show_progress = not args.quiet and sys.stderr.isatty()
    with HistoryStore(args.db, create=True) as store:
        logs = [] if args.listen is not None else ordered_logs(args)
        tracker = gearbox_tracker(store, args, logs)
        if args.listen is not None:
            known = store.find_gearbox(args.gearbox)
            warn, limit = (
                (known.warn_arcmin, known.limit_arcmin) if known is not None else (args.warn_arcmin, args.limit_arcmin)
            )
            figures = history_figures(store, args.gearbox)
            with mqtt_publisher(args.mqtt, args.gearbox, warn, limit, tls=mqtt_tls(args), figures=figures) as publisher:
                with _progress_bar(f"{args.listen} live", show_progress) as progress:
                    result = _track_live(tracker, args, progress, None if publisher is None else publisher.publish)
                if publisher is not None:
                    result.counters.update(publisher.counts())
            report(result, args.json)
            if publisher is not None and not args.json:
                print(mqtt_summary_line(publisher))
            return 0
        for result in track_logs(tracker, args, logs, show_progress):
            report(result, args.json)
    return 0


def gearbox_tracker(store: HistoryStore, args: argparse.Namespace, logs: list[str]) -> GearboxTracker:
    """The tracker of the gearbox ``args`` name, its alarm levels stored (``--diagnose`` reads the first of
    ``logs``)."""
    from ..tracking import GearboxTracker

    given = {"memory_reversals": args.memory_reversals, "sample_period_s": args.sample_period}
    params = {name: value for name, value in given.items() if value is not None}
    if args.diagnose:
        params.update(_diagnosed_effects(store, args, logs[0]))
    if args.warn_arcmin is not None or args.limit_arcmin is not None:
        store.set_alarm_levels(args.gearbox, args.ratio, warn_arcmin=args.warn_arcmin, limit_arcmin=args.limit_arcmin)
    return GearboxTracker(
        store, args.gearbox, args.ratio, every_s=args.every, limit_arcmin=args.limit_arcmin, estimator_params=params,
        play_method=args.play_method, no_torque_why=no_torque_reason(logs[0] if logs else None, args),
    )  # fmt: skip


def _log_options(args: argparse.Namespace, path: str) -> dict[str, Any]:
    return log_options(argparse.Namespace(**{**vars(args), "log": path}))


#: Per log (its path): what a fleet manifest says of it (``start`` UNIX seconds, ``operating_hours``).
PerLog = dict[str, dict[str, float]]


def check_one_log_options(args: argparse.Namespace, logs: int, note: str) -> None:
    """``--start`` and ``--operating-hours`` describe one log: refuse them with ``logs`` other than one."""
    for option in ("start", "operating_hours"):
        if getattr(args, option) is not None and logs != 1:
            flag = "--" + option.replace("_", "-")
            raise InvalidParameterError(f"{flag} is given for one log; {logs} logs were given ({note})")


def clock_of(args: argparse.Namespace, path: str | None, per_log: PerLog | None = None) -> ClockOptions:
    """What the command line (and a manifest's entry for ``path``) says of a log's clock."""
    from ..clocks import ClockOptions

    start = (per_log or {}).get(path or "", {}).get("start", args.start)
    pattern = args.start_from_name if start is None else None
    return ClockOptions(start_unix_s=start, start_pattern=pattern, time_unit=args.time_unit)


def usage_of(args: argparse.Namespace, path: str | None, per_log: PerLog | None = None) -> MachineUsage:
    """How the command line (and a manifest's entry for ``path``) says a log tells the machine's hours."""
    from ..hour_meter import MachineUsage, hours_per_unit

    reading = (per_log or {}).get(path or "", {}).get("operating_hours", args.operating_hours)
    column = None if reading is not None else args.hours_column
    return MachineUsage(operating_hours=reading, hours_column=column, hours_per_count=hours_per_unit(args.hours_unit))


def ordered_logs(args: argparse.Namespace, per_log: PerLog | None = None) -> list[str]:
    """The logs given (a ``listen --raw-log`` folder: its finished captures), sorted by their first
    sample's calendar time; a note on stderr when that is not the order given."""
    from ..tracking import in_time_order, log_files

    given = [f for path in args.logs for f in log_files(path)]
    check_one_log_options(args, len(given), "folders count their files")
    ordered = in_time_order(given, lambda p: _log_options(args, p), lambda p: clock_of(args, p, per_log))
    if ordered != given and not args.quiet:
        print(
            f"note: {args.gearbox}: logs tracked in the order of their first samples' time: {', '.join(ordered)}",
            file=sys.stderr,
        )
    return ordered


def track_logs(
    tracker: GearboxTracker,
    args: argparse.Namespace,
    logs: list[str],
    show_progress: bool = False,
    per_log: PerLog | None = None,
) -> Iterator[TrackResult]:
    """Track ``logs`` in this order into the tracker's gearbox, one result per log as it completes."""
    for path in logs:
        with _progress_bar(path, show_progress) as progress:
            clock, usage = clock_of(args, path, per_log), usage_of(args, path, per_log)
            yield tracker.track_log(path, _log_options(args, path), progress=progress, clock=clock, usage=usage)


def _diagnosed_effects(store: HistoryStore, args: argparse.Namespace, first: str) -> dict[str, Any]:
    """``{"effects": [...]}``: the named effects ``diagnose`` finds in the ``first`` log, for a new gearbox
    (``{}`` for a gearbox with a checkpoint: its estimator carries its effects)."""
    known = store.find_gearbox(args.gearbox)
    if known is not None and known.checkpoint is not None:
        return {}
    from ..diagnostics.loop import diagnose
    from ..replay import read_log_arrays

    chunk = read_log_arrays(first, **_log_options(args, first))
    return {"effects": diagnose(chunk, args.ratio).effects}


@contextmanager
def _progress_bar(label: str, show: bool) -> Iterator[ProgressCallback]:
    """A tqdm bar on stderr (samples, samples/s, the current estimate), as a progress callback."""
    from tqdm import tqdm

    with tqdm(desc=label, unit=" samples", unit_scale=True, disable=not show, leave=False) as bar:

        def progress(samples: int, backlash_deg: float | None) -> None:
            bar.update(samples - bar.n)
            if backlash_deg is not None:
                bar.set_postfix_str(f"backlash {backlash_deg:.4f} deg")

        yield progress


def _track_live(
    tracker: GearboxTracker, args: argparse.Namespace, progress: ProgressCallback, on_row: RowCallback | None = None
) -> TrackResult:
    """Open the live source as ``listen`` does and track it until it ends (duration, Ctrl-C, timeout);
    ``on_row(row, time_unix_s)`` gets each estimate stored (``--mqtt`` publishes it)."""
    if args.listen == "can":
        label, open_source = f"can {args.interface} {args.channel}", open_can_source
    else:
        label, open_source = f"serial {args.port}", open_serial_source
    with open_source(args) as source, ctrl_c_ends_the_run(source.request_stop, label):
        return tracker.track_source(source, label, progress=progress, on_row=on_row)


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
    if result.note is not None:
        line += f" ({result.note})"
    last = result.last_estimate
    if last is not None:
        play, std, hours = last["backlash_deg"], last["backlash_std_deg"], last["operating_hours"]
        if play is not None and math.isfinite(play):
            line += f"; backlash {play:.4f} deg (std {std:.4f}) after {hours:.3f} operating hours logged"
        else:  # stored as not observable: no figure, never a nan
            line += f"; the play not observable in the last estimate, after {hours:.3f} operating hours logged"
    if result.machine_hours is not None:
        line += f"; hour meter {result.machine_hours:.2f} h at its end"
    counts = describe_counts(result.counters)
    clock = f"; placed in time by the {result.clock}" if result.clock else ""
    print(f"{line}\n  source: {counts}{clock}" if counts or clock else line)


# -- one gearbox of a fleet manifest (track --manifest, cli/_fleet.py), tracked as track tracks it alone --------


class _OptionError(argparse.ArgumentParser):
    """An argument parser whose errors raise InvalidParameterError instead of exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InvalidParameterError(message)


@cache
def _track_parser() -> argparse.ArgumentParser:
    """``track``'s own option parser (as ``online-backlash track`` builds it), raising on bad options."""
    root = argparse.ArgumentParser(prog="online-backlash")
    subparsers = root.add_subparsers(parser_class=_OptionError)
    add_subparser(subparsers)
    return subparsers.choices["track"]


def parse_track_argv(argv: list[str]) -> argparse.Namespace:
    """One gearbox's ``track`` arguments, parsed and checked as ``track`` checks them."""
    args = _track_parser().parse_args(argv)
    check_track_args(args)
    return args


def track_command_line_options() -> frozenset[str]:
    """The options of ``track`` (dest names) that are the command's, not one gearbox's: a fleet manifest may not
    set them and ``--manifest`` does not hand them to a gearbox. They are the store and the output
    (:data:`COMMAND_OPTIONS`) and the options of the groups :data:`LIVE_GROUP` and :data:`FLEET_GROUP`, read
    from the parser, so an option added to those groups is the command's without being listed again."""
    parser = _track_parser()
    grouped = (
        g for g in parser._action_groups if g.title in (LIVE_GROUP, FLEET_GROUP)
    )  # argparse keeps no public list
    return COMMAND_OPTIONS | {action.dest for group in grouped for action in group._group_actions}


def track_defaults() -> dict[str, object]:
    """Every option of ``track`` (dest name) with its default."""
    return {k: v for k, v in vars(_track_parser().parse_args(["--db", "-"])).items() if k != "func"}


def track_gearbox(job: GearboxJob) -> GearboxOutcome:
    """Track one gearbox of a fleet (a Dask task): its logs in time order into the store, as ``track`` does.

    An error of the gearbox's options, logs or store is returned in the outcome (the logs before
    it are stored); the task is not retried for it.
    """
    from ..history.store import HistoryStore

    # Dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536 (distributed.nanny.pre-spawn-environ), so
    # glibc handed every block a log's reading frees back to the kernel and faulted the next one in afresh: 94,000
    # page faults and 1.6-1.7x the CPU of the same gearbox tracked in the CLI's process (docs/benchmarks.md). A worker
    # tracks one log after another: its blocks are reused instead, as in the CLI's own one-shot commands.
    keep_freed_memory()
    started, cpu = time.perf_counter(), time.process_time()
    outcome = GearboxOutcome(job.id, worker=f"{socket.gethostname()}:{os.getpid()}")
    try:
        args = parse_track_argv(list(job.argv))
        with HistoryStore(args.db, create=True) as store:
            per_log = {path: dict(keys) for path, keys in job.per_log.items()}
            logs = ordered_logs(argparse.Namespace(**{**vars(args), "quiet": True}), per_log)
            tracker = gearbox_tracker(store, args, logs)
            for result in track_logs(tracker, args, logs, per_log=per_log):
                outcome.results.append(result)
    except (BacklashError, OSError) as exc:
        outcome.error = str(exc)
    outcome.elapsed_s = time.perf_counter() - started
    outcome.cpu_s = time.process_time() - cpu
    return outcome

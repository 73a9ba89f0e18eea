"""``online-backlash track --manifest fleet.toml --db URL [--workers N | --scheduler tcp://HOST:PORT]``.

Every gearbox of the manifest is tracked as ``track`` would track it alone (its options checked
by ``track``'s own parser, its logs in time order, resumed from the store's checkpoint), one Dask
task per gearbox (:mod:`online_backlash.fleet`).
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import time
from functools import cache

from .._allocator import keep_freed_memory
from ..errors import BacklashError, InvalidParameterError
from ..fleet import GearboxJob, GearboxOutcome, load_manifest, run_fleet
from ..fleet.manifest import NOT_PER_GEARBOX
from ..fleet.progress import FleetProgress
from ..fleet.runner import default_workers
from . import track as track_command


class _OptionError(argparse.ArgumentParser):
    """An argument parser whose errors raise InvalidParameterError instead of exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InvalidParameterError(message)


@cache
def _track_parser() -> argparse.ArgumentParser:
    """``track``'s own option parser (as ``online-backlash track`` builds it), raising on bad options."""
    root = argparse.ArgumentParser(prog="online-backlash")
    subparsers = root.add_subparsers(parser_class=_OptionError)
    track_command.add_subparser(subparsers)
    return subparsers.choices["track"]


def parse_track_argv(argv: list[str]) -> argparse.Namespace:
    """One gearbox's ``track`` arguments, parsed and checked as ``track`` checks them."""
    args = _track_parser().parse_args(argv)
    track_command.check_track_args(args)
    return args


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
            logs = track_command.ordered_logs(argparse.Namespace(**{**vars(args), "quiet": True}), per_log)
            tracker = track_command.gearbox_tracker(store, args, logs)
            for result in track_command.track_logs(tracker, args, logs, per_log=per_log):
                outcome.results.append(result)
    except (BacklashError, OSError) as exc:
        outcome.error = str(exc)
    outcome.elapsed_s = time.perf_counter() - started
    outcome.cpu_s = time.process_time() - cpu
    return outcome


def _absolute_db(db: str) -> str:
    """A store path relative to here made absolute (workers may run elsewhere); URLs unchanged."""
    return db if "://" in db else os.path.abspath(db)


def run_manifest(args: argparse.Namespace) -> int:
    """``track --manifest``: every gearbox of the manifest, then one report per log and a summary line."""
    from ..history.store import HistoryStore, resolve_url

    defaults = track_defaults()
    given = sorted(k for k, v in defaults.items() if k not in NOT_PER_GEARBOX and getattr(args, k) != v)
    if given:
        flags = ", ".join("--" + k.replace("_", "-") for k in given)
        raise InvalidParameterError(f"{flags}: with --manifest, per-gearbox options go into the manifest ([defaults] or a [[gearbox]] table)")
    if args.workers is not None and args.scheduler is not None:
        raise InvalidParameterError("give --workers N (a local cluster) or --scheduler URL (an existing one), not both")
    if args.workers is not None and args.workers < 0:
        raise InvalidParameterError(f"--workers must be 0 (serial) or more, got {args.workers}")
    db = _absolute_db(args.db)
    jobs = load_manifest(args.manifest, db, parse_track_argv, defaults)
    with HistoryStore(db, create=True):
        pass  # created once here, not by several workers at once
    parallel = args.scheduler is not None or args.workers != 0
    workers = args.workers if args.workers is not None else default_workers()
    if parallel and resolve_url(db).get_backend_name() == "sqlite":
        print(
            "note: SQLite store: the workers' writes are serialised by SQLite's file lock (one commit at a time); "
            "use PostgreSQL (--db postgresql://...) for many concurrent writers",
            file=sys.stderr,
        )
    show = not (args.quiet or args.json) and sys.stderr.isatty()
    started = time.perf_counter()
    with FleetProgress(len(jobs), show) as progress:
        outcomes = run_fleet(jobs, track_gearbox, workers=args.workers if args.scheduler is None else None, scheduler=args.scheduler, on_done=progress.done)
    elapsed = time.perf_counter() - started
    failed = 0
    for outcome in outcomes:
        for result in outcome.results:
            track_command.report(result, args.json)
        if outcome.error is not None:
            failed += 1
            print(f"error: {args.manifest}: gearbox {outcome.gearbox_id}: {outcome.error}", file=sys.stderr)
    if not args.json:
        samples = sum(o.samples_fed for o in outcomes)
        where = f"on {args.scheduler}" if args.scheduler else "serially" if not parallel else f"on {workers} local workers"
        rate = samples / elapsed if elapsed > 0 else 0.0
        print(
            f"fleet: {len(outcomes) - failed} of {len(outcomes)} gearboxes tracked, {sum(len(o.results) for o in outcomes)} logs, "
            f"{samples} samples in {elapsed:.1f} s ({rate:,.0f} samples/s) {where}"
        )
    return 1 if failed else 0

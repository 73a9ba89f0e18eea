"""``online-backlash track --manifest fleet.toml --db URL [--workers N | --scheduler tcp://HOST:PORT]``.

Every gearbox of the manifest is tracked as ``track`` would track it alone (its options checked
by ``track``'s own parser, its logs in time order, resumed from the store's checkpoint), one Dask
task per gearbox (:mod:`online_backlash.fleet`): the task is ``track``'s (:func:`.track.track_gearbox`),
handed in with its parser, so that this module does not import ``track`` (``track`` imports it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..errors import InvalidParameterError
from ..fleet import load_manifest, run_fleet
from ..fleet.progress import FleetProgress
from ..fleet.runner import GearboxTask, default_workers

if TYPE_CHECKING:
    from ..tracking import TrackResult


def _absolute_db(db: str) -> str:
    """A store path relative to here made absolute (workers may run elsewhere); URLs unchanged."""
    return db if "://" in db else os.path.abspath(db)


def run_manifest(
    args: argparse.Namespace,
    task: GearboxTask,
    parse_track_argv: Callable[[list[str]], argparse.Namespace],
    defaults: dict[str, object],
    command_line: frozenset[str],
    report: Callable[[TrackResult, bool], None],
) -> int:
    """``track --manifest``: every gearbox of the manifest, then one report per log and a summary line.

    ``track`` hands in what is its own (so that this module does not import it): the task that tracks one
    gearbox, its parser of one gearbox's options and their defaults, the options that are the command's (not a
    gearbox's), and its report of one log.
    """
    from ..history.store import HistoryStore, resolve_url

    given = sorted(k for k, v in defaults.items() if k not in command_line and getattr(args, k) != v)
    if given:
        flags = ", ".join("--" + k.replace("_", "-") for k in given)
        raise InvalidParameterError(
            f"{flags}: with --manifest, per-gearbox options go into the manifest ([defaults] or a [[gearbox]] table)"
        )
    if args.workers is not None and args.scheduler is not None:
        raise InvalidParameterError("give --workers N (a local cluster) or --scheduler URL (an existing one), not both")
    if args.workers is not None and args.workers < 0:
        raise InvalidParameterError(f"--workers must be 0 (serial) or more, got {args.workers}")
    db = _absolute_db(args.db)
    jobs = load_manifest(args.manifest, db, parse_track_argv, defaults, command_line)
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
        outcomes = run_fleet(
            jobs,
            task,
            workers=args.workers if args.scheduler is None else None,
            scheduler=args.scheduler,
            on_done=progress.done,
        )
    elapsed = time.perf_counter() - started
    failed = 0
    for outcome in outcomes:
        for result in outcome.results:
            report(result, args.json)
        if outcome.error is not None:
            failed += 1
            print(f"error: {args.manifest}: gearbox {outcome.gearbox_id}: {outcome.error}", file=sys.stderr)
    if not args.json:
        samples = sum(o.samples_fed for o in outcomes)
        where = (
            f"on {args.scheduler}" if args.scheduler else "serially" if not parallel else f"on {workers} local workers"
        )
        rate = samples / elapsed if elapsed > 0 else 0.0
        print(
            f"fleet: {len(outcomes) - failed} of {len(outcomes)} gearboxes tracked, "
            f"{sum(len(o.results) for o in outcomes)} logs, "
            f"{samples} samples in {elapsed:.1f} s ({rate:,.0f} samples/s) {where}"
        )
    return 1 if failed else 0

"""The fleet manifest: a TOML file naming every gearbox, its logs and its ``track`` options.

::

    [defaults]               # applies to every gearbox; a gearbox's own key wins
    ratio = 30
    every = 60
    limit_arcmin = 21
    warn_arcmin = 18

    [[gearbox]]
    id = "GB-7"
    logs = "logs/gb7/*.csv.gz"       # a glob, or a list of paths and globs; relative to this file
    columns = { time = "t", motor = "motor_counts", load = "load_counts" }
    units = "counts"
    motor_cpr = 16384
    load_cpr = 16384

    [[gearbox]]
    id = "GB-8"
    ratio = -50
    logs = ["can/gb8/day01.blf", "can/gb8/day02.blf"]
    dbc = "rig"
    motor_signal = "MotorAngle.Count"
    load_signal = "LoadAngle.Count"

    [[gearbox]]
    id = "GB-9"
    ratio = 30
    logs = [                         # a log's own keys: its start and the hour meter at its first sample
      { path = "gb9/a.csv", start = 2026-11-02T08:00:00Z, operating_hours = 1234.5 },
      { path = "gb9/b.csv", start = "2026-11-03T08:00:00", operating_hours = 1250.6 },
    ]

Every key is a ``track`` option with its dashes written as underscores (``id`` is ``--gearbox``;
``true`` gives a flag, ``false`` leaves it out; a table such as ``columns`` becomes
``name=column,...``). Each gearbox's options are turned into the argument list ``track`` would be
given and checked by ``track``'s own parser, so every option is accepted and checked the same
way; an unknown key is an error naming the manifest, the gearbox table and the key, with the
closest option. The store (``--db``) and the fleet's own options come from the command line.
A log given as a table carries its own :data:`LOG_KEYS`: ``start`` (a TOML date-time or an ISO
8601 string; UTC unless it names a zone) and ``operating_hours`` (the machine's hour meter at
its first sample), what ``--start`` and ``--operating-hours`` say for one log tracked alone.
"""

from __future__ import annotations

import argparse
import datetime as dt
import difflib
import glob
import math
import os
import re
import sys
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import BacklashError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: Top-level tables of a manifest.
TABLES = ("defaults", "gearbox")
#: Keys of a log given as a table: its path, and what ``track --start``/``--operating-hours`` say of one log.
LOG_KEYS = ("path", "start", "operating_hours")

#: ``parse(argv)``: track's option parser; raises BacklashError (argparse's message) on bad options.
ParseOptions = Callable[[list[str]], argparse.Namespace]


class ManifestError(BacklashError, ValueError):
    """A manifest is not valid; the message names the file, the gearbox table and the key."""


@dataclass(frozen=True)
class GearboxJob:
    """One gearbox of a fleet: its id and the ``track`` arguments that track it (store included).

    ``argv`` is what ``online-backlash track`` would be given for this gearbox alone; ``logs``
    the log paths it names, absolute, in the manifest's order (``track`` sorts them by time);
    ``per_log`` what the manifest says of single logs (path -> ``start`` in UNIX seconds,
    ``operating_hours`` in hours).
    """

    id: str
    argv: tuple[str, ...]
    logs: tuple[str, ...]
    per_log: Mapping[str, Mapping[str, float]] = field(default_factory=dict)


def load_manifest(
    path: str | os.PathLike[str], db: str, parse: ParseOptions, known: Collection[str], command_line: Collection[str]
) -> list[GearboxJob]:
    """Read a fleet manifest and check every gearbox's options with ``track``'s parser.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML manifest; log paths and globs in it are relative to its folder.
    db : str
        The store every gearbox is tracked into (``--db``).
    parse : callable
        ``parse(argv) -> Namespace``: track's option parser, raising BacklashError on bad options.
    known : collection of str
        track's option names with dashes as underscores (the parser's ``dest`` names).
    command_line : collection of str
        Those of ``known`` that are the command's, not a gearbox's (the store, the output, live tracking, the
        fleet's run: ``track``'s parser says which); a manifest that sets one is refused with that reason.

    Returns
    -------
    list of GearboxJob
        One per ``[[gearbox]]`` table, in the manifest's order.
    """
    name = os.fspath(path)
    tables = _read_toml(name)
    for key in tables:
        if key not in TABLES:
            raise ManifestError(
                f"{name}: unknown table {key!r}{_closest(key, TABLES)}; a manifest has [defaults] and [[gearbox]] "
                "tables"
            )
    defaults = tables.get("defaults", {})
    gearboxes = tables.get("gearbox")
    if not isinstance(defaults, dict):
        raise ManifestError(f"{name}: [defaults] must be a table")
    if not isinstance(gearboxes, list) or not gearboxes or not all(isinstance(g, dict) for g in gearboxes):
        raise ManifestError(f"{name}: no [[gearbox]] tables: give one per gearbox, each with an id and its logs")
    options = set(known) - set(command_line) - {"gearbox"}
    _check_keys(defaults, options, command_line, f"{name}: [defaults]")
    jobs: list[GearboxJob] = []
    seen: set[str] = set()
    folder = Path(name).resolve().parent
    for number, table in enumerate(gearboxes, 1):
        gearbox_id = table.get("id")
        where = f"{name}: [[gearbox]] #{number}" + (f" (id {gearbox_id!r})" if isinstance(gearbox_id, str) else "")
        if not isinstance(gearbox_id, str) or not gearbox_id:
            raise ManifestError(f'{where}: needs an id, e.g. id = "GB-7"')
        if gearbox_id in seen:
            raise ManifestError(f"{where}: the id {gearbox_id!r} is given twice")
        seen.add(gearbox_id)
        _check_keys(table, options, command_line, where)
        merged = {**defaults, **{k: v for k, v in table.items() if k != "id"}}
        logs, per_log = _logs(merged.pop("logs", None), folder, where)
        argv = ["--db", db, f"--gearbox={gearbox_id}", *_option_argv(merged, where), "--", *logs]
        try:
            parse(argv)
        except BacklashError as exc:
            raise ManifestError(f"{where}: {exc}") from exc
        jobs.append(GearboxJob(gearbox_id, tuple(argv), tuple(logs), per_log))
    return jobs


def _read_toml(name: str) -> dict[str, Any]:
    try:
        with open(name, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        line = re.search(r"\(at line (\d+), column \d+\)", message)
        where = f"{name}:{line.group(1)}" if line else name
        reason = re.sub(r" \(at line .*\)$", "", message)
        raise ManifestError(f"{where}: not valid TOML: {reason}") from exc


def _check_keys(table: Mapping[str, Any], options: Collection[str], command_line: Collection[str], where: str) -> None:
    for key in table:
        if key in ("id", "logs"):
            continue
        if key in command_line:
            raise ManifestError(
                f"{where}: {key!r} is not a per-gearbox option (the store, the output, live tracking and the fleet's "
                "run are given on the command line)"
            )
        if key not in options:
            hint = _closest(key, [*options, "id", "logs"])
            raise ManifestError(
                f"{where}: unknown key {key!r}{hint} (keys are track's options with dashes as underscores)"
            )


def _closest(key: str, names: Collection[str]) -> str:
    match = difflib.get_close_matches(key, sorted(names), n=1)
    return f"; did you mean {match[0]!r}?" if match else ""


def _logs(value: Any, folder: Path, where: str) -> tuple[list[str], dict[str, dict[str, float]]]:
    """The logs of one gearbox: each entry a path or a glob relative to ``folder`` (globs sorted by name), or a
    table with a ``path`` and the log's own keys (:data:`LOG_KEYS`); and those keys by absolute path."""
    if isinstance(value, (str, dict)):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, (str, dict)) for v in value):
        raise ManifestError(f'{where}: logs must be a path or glob, or a list of them, e.g. logs = "gb7/*.csv.gz"')
    found: list[str] = []
    per_log: dict[str, dict[str, float]] = {}
    for entry in value:
        pattern = entry if isinstance(entry, str) else _log_table(entry, where)
        full = str(folder / os.path.expanduser(pattern))
        matches = (
            sorted(glob.glob(full, recursive=True)) if glob.has_magic(full) else [full] if os.path.exists(full) else []
        )
        if not matches:
            raise ManifestError(f"{where}: logs: nothing matches {pattern!r} (in {folder})")
        if isinstance(entry, dict):
            if len(matches) != 1:
                raise ManifestError(
                    f"{where}: logs: {pattern!r} has a start or hour meter of its own, so it names one log, "
                    f"not {len(matches)}"
                )
            per_log[matches[0]] = _log_keys(entry, f"{where}: log {pattern!r}")
        found.extend(m for m in matches if m not in found)
    return found, per_log


def _log_table(entry: dict[str, Any], where: str) -> str:
    """The path of a log given as a table (its keys checked)."""
    unknown = [k for k in entry if k not in LOG_KEYS]
    if unknown:
        hint = _closest(unknown[0], LOG_KEYS)
        raise ManifestError(f"{where}: logs: unknown key {unknown[0]!r}{hint} (a log's keys: {', '.join(LOG_KEYS)})")
    path = entry.get("path")
    if not isinstance(path, str) or not path:
        example = '{ path = "gb7/day01.csv", start = ... }'
        raise ManifestError(f"{where}: logs: a log given as a table needs its path, e.g. {example}")
    return path


def _log_keys(entry: dict[str, Any], where: str) -> dict[str, float]:
    """A log's ``start`` (UNIX seconds) and ``operating_hours`` (hours), checked."""
    keys: dict[str, float] = {}
    start = entry.get("start")
    if start is not None:
        if isinstance(start, str):
            try:
                start = dt.datetime.fromisoformat(start)
            except ValueError:
                example = "2026-11-02T08:00:00"
                raise ManifestError(f"{where}: start = {start!r} is not an ISO 8601 date-time like {example}") from None
        if not isinstance(start, dt.datetime):
            raise ManifestError(f"{where}: start = {start!r} is not a date-time (e.g. 2026-11-02T08:00:00Z)")
        keys["start"] = (start if start.tzinfo is not None else start.replace(tzinfo=dt.timezone.utc)).timestamp()
    hours = entry.get("operating_hours")
    if hours is not None:
        if isinstance(hours, bool) or not isinstance(hours, (int, float)) or not math.isfinite(hours) or hours < 0:
            raise ManifestError(f"{where}: operating_hours = {hours!r} is not an hour-meter reading (hours >= 0)")
        keys["operating_hours"] = float(hours)
    return keys


def _option_argv(options: Mapping[str, Any], where: str) -> list[str]:
    """``{"limit_arcmin": 21, "skip_bad_rows": True}`` -> ``["--limit-arcmin=21", "--skip-bad-rows"]``."""
    argv: list[str] = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if isinstance(value, bool):
            argv.extend([flag] if value else [])
        elif isinstance(value, (str, int, float)):
            argv.append(f"{flag}={value}")
        elif isinstance(value, dict) and all(isinstance(v, (str, int, float)) for v in value.values()):
            argv.append(f"{flag}=" + ",".join(f"{k}={v}" for k, v in value.items()))
        else:
            raise ManifestError(
                f"{where}: {key} = {value!r}: expected one value (a string, number, true/false, or a table of names)"
            )
    return argv

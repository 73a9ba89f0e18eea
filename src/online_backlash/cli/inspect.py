"""``online-backlash inspect FILE``: list the columns, channels or CAN IDs a file holds."""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import TYPE_CHECKING

from ._common import add_csv_dialect_options, csv_dialect_options, node_id_type, print_json

if TYPE_CHECKING:
    from ..inspection import CanIdInfo, FileSummary


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "inspect",
        help="list the columns, channels or CAN IDs a file holds",
        description=(
            "List what a recorded file holds, to find the names for --columns or --motor-signal/--load-signal: "
            "CSV, Parquet and Arrow columns (type, rows); MDF channels (group, unit, rate, samples); "
            "TDMS group/channels (unit, length, rate); CAN log IDs (frames, rate, DBC message names with --dbc)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("file", help="a .csv[.gz], .parquet, .arrow/.feather, .mf4/.mdf, .tdms file or a CAN log (.asc .blf .log .trc .mf4 ...)")
    parser.add_argument("--dbc", metavar="FILE", help="name the CAN IDs of a CAN log by this DBC ('rig' for the shipped rig.dbc)")
    parser.add_argument("--eds", metavar="FILE", help="name the COB-IDs of a CAN log by this CANopen EDS/DCF (its TPDOs and mapped objects; with --node)")
    parser.add_argument("--node", type=node_id_type, metavar="N", help="node-ID of the --eds drive")
    parser.add_argument("--load-node", type=node_id_type, metavar="N", help="a second CANopen node to name (its dictionary: --load-eds, else --eds)")
    parser.add_argument("--load-eds", metavar="FILE", help="EDS or DCF of --load-node")
    parser.add_argument("--filter", metavar="PATTERN", help="only names matching this shell pattern or containing this word (case-insensitive)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_csv_dialect_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..inspection import inspect_file  # imported here: the readers load only for this subcommand

    dbc = args.dbc
    if dbc == "rig":
        from ..codecs.dbc import RIG_DBC

        dbc = RIG_DBC
    summary = inspect_file(args.file, dbc=dbc, **csv_dialect_options(args))
    if args.eds is not None:
        summary = _canopen_named(summary, args)
    summary = summary.matching(args.filter)
    if args.json:
        print_json(summary.as_dict())
        return 0
    table: list[tuple[str, ...]]
    if summary.kind == "can":
        print(f"{summary.path}: CAN log, {summary.frames} frames, {len(summary.can_ids)} IDs")
        table = [("id", "frames", "rate_hz", "message")]
        table += [(i.label, str(i.frames), _number(i.rate_hz), i.message or "") for i in summary.can_ids]
    else:
        print(f"{summary.path}: {summary.kind}, {len(summary.channels)} {'channels' if summary.kind in ('mdf', 'tdms') else 'columns'}")
        table = [("name", "group", "unit", "type", "samples", "rate_hz")]
        table += [
            (c.name, "" if c.group is None else str(c.group), c.unit or "", c.dtype, "" if c.samples is None else str(c.samples), _number(c.rate_hz))
            for c in summary.channels
        ]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip())
    return 0


def _canopen_named(summary: FileSummary, args: argparse.Namespace) -> FileSummary:
    """The CAN IDs named by the CANopen dictionaries: SYNC, each TPDO with its objects, the predefined services."""
    from ..codecs.canopen import cob_id_names, service_name
    from ..errors import InvalidParameterError

    if args.node is None:
        raise InvalidParameterError(f"--eds {args.eds}: give --node N, the node-ID of the drive")
    if summary.kind != "can":
        raise InvalidParameterError(f"{summary.path}: --eds names the frames of a CAN log, and this is a {summary.kind} file")
    nodes = [(args.eds, args.node)] + ([] if args.load_node is None else [(args.load_eds or args.eds, args.load_node)])
    names = cob_id_names(nodes)

    def name(info: CanIdInfo) -> str | None:
        return info.message if info.extended else names.get(info.can_id) or service_name(info.can_id) or info.message

    return replace(summary, can_ids=[replace(i, message=name(i)) for i in summary.can_ids])


def _number(value: float | None) -> str:
    return "" if value is None else f"{value:g}"

"""``online-backlash inspect FILE``: list the columns, channels or CAN IDs a file holds; with ``--eds``/``--node``
(one pair per node, repeated), each CANopen node's TPDO mapping, and the COB-IDs of a CAN log named by it."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from ._options import add_csv_dialect_options, csv_dialect_options, log_formats, node_id_type
from ._output import print_json

if TYPE_CHECKING:
    from ..codecs.canopen import NodeMapping
    from ..inspection import CanIdInfo, FileSummary


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "inspect",
        help="list the columns, channels or CAN IDs a file holds",
        description=(
            "List what a recorded file holds, to find the names for --columns or --motor-signal/--load-signal: "
            "CSV, Parquet and Arrow columns (type, rows); MDF channels (group, unit, rate, samples); "
            "TDMS group/channels (unit, length, rate); MATLAB and HDF5 variables (shape, type, length, unit); "
            "CAN log IDs (frames, rate, DBC message names with --dbc). "
            "With --eds/--node (repeated: one pair per node, or one --eds for every --node), each CANopen node's TPDO "
            "mapping (COB-ID, transmission type, mapped objects), and a CAN log's COB-IDs named by it; FILE may then "
            "be omitted."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "file",
        nargs="?",
        help=f"a recorded file: {log_formats(inspected=True)}",
    )
    parser.add_argument(
        "--dbc", metavar="FILE", help="name the CAN IDs of a CAN log by this DBC ('rig' for the shipped rig.dbc)"
    )
    parser.add_argument(
        "--eds",
        action="append",
        metavar="FILE",
        help="a CANopen EDS/DCF: list its TPDO mapping and name a CAN log's COB-IDs by it (with --node; repeat both "
        "for several nodes)",
    )
    parser.add_argument(
        "--node",
        action="append",
        type=node_id_type,
        metavar="N",
        help="node-ID of the --eds drive (the n-th --node goes with the n-th --eds)",
    )
    parser.add_argument(
        "--load-node",
        type=node_id_type,
        metavar="N",
        help="a second CANopen node to name (its dictionary: --load-eds, else --eds)",
    )
    parser.add_argument("--load-eds", metavar="FILE", help="EDS or DCF of --load-node")
    parser.add_argument(
        "--filter",
        metavar="PATTERN",
        help="only names matching this shell pattern or containing this word (case-insensitive)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_csv_dialect_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..inspection import inspect_file  # imported here: the readers load only for this subcommand

    dbc = args.dbc
    if dbc == "rig":
        from ..codecs.dbc import RIG_DBC

        dbc = RIG_DBC
    nodes = _canopen_nodes(args)
    summary: FileSummary | None = None
    out: dict[str, Any] = {}
    if args.file is not None:
        summary = inspect_file(args.file, dbc=dbc, **csv_dialect_options(args))
        if nodes:
            summary = _canopen_named(summary, nodes)
        summary = summary.matching(args.filter)
        out = summary.as_dict()
    if nodes:
        out["nodes"] = [node.as_dict() for node in nodes]
    if summary is not None and summary.truncated is not None:
        readable = "the counts are what is readable up to the cut"
        print(f"warning: {summary.path}: {summary.truncated}; {readable}", file=sys.stderr)
    if args.json:
        print_json(out)
        return 0
    if summary is not None:
        _print_summary(summary)
    for node in nodes:
        _print_node(node)
    return 0


def _print_summary(summary: FileSummary) -> None:
    table: list[tuple[str, ...]]
    if summary.kind == "can":
        print(f"{summary.path}: CAN log, {summary.frames} frames, {len(summary.can_ids)} IDs")
        table = [("id", "frames", "rate_hz", "message")]
        table += [(i.label, str(i.frames), _number(i.rate_hz), i.message or "") for i in summary.can_ids]
    else:
        nouns = {"mdf": "channels", "tdms": "channels", "mat": "variables", "mat-v7.3": "variables"}
        noun = nouns.get(summary.kind, "variables" if summary.kind == "hdf5" else "columns")
        print(f"{summary.path}: {summary.kind}, {len(summary.channels)} {noun}")
        shaped = any(c.shape for c in summary.channels)  # MATLAB and HDF5 arrays: their shape too
        table = [("name", "group", "unit", "type", *(("shape",) if shaped else ()), "samples", "rate_hz")]
        table += [
            (
                c.name,
                "" if c.group is None else str(c.group),
                c.unit or "",
                c.dtype,
                *((c.shape or "",) if shaped else ()),
                "" if c.samples is None else str(c.samples),
                _number(c.rate_hz),
            )
            for c in summary.channels
        ]
    _print_table(table)


def _print_table(table: list[tuple[str, ...]]) -> None:
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip())


def _print_node(node: NodeMapping) -> None:
    """One node's TPDOs: number, COB-ID, transmission type (trigger), the objects mapped."""
    print(f"node {node.node_id} ({node.path}): {len(node.tpdos)} valid TPDOs, SYNC COB-ID 0x{node.sync_cob_id:03X}")
    table: list[tuple[str, ...]] = [("tpdo", "cob_id", "type", "objects")]
    table += [
        (
            str(p.number),
            f"0x{p.cob_id:03X}",
            f"{p.transmission_type} ({p.trigger})",
            ", ".join(f"{o.label} [{o.bit_length} bit]" for o in p.objects),
        )
        for p in node.tpdos
    ]
    _print_table(table)


def _canopen_nodes(args: argparse.Namespace) -> list[NodeMapping]:
    """The ``(--eds, --node)`` pairs (one --eds for every --node, or one each; ``--load-node``/``--load-eds``
    add one more, as in ``estimate``), each node's mapping read from its dictionary."""
    from ..errors import InvalidParameterError

    eds, node_ids = args.eds or [], args.node or []
    if args.file is None and not eds:
        raise InvalidParameterError(
            "give a FILE to inspect, or --eds FILE --node N to list a CANopen node's TPDO mapping"
        )
    if not eds:
        if node_ids or args.load_node is not None or args.load_eds is not None:
            raise InvalidParameterError("--node, --load-node and --load-eds go with --eds FILE, the node's EDS/DCF")
        return []
    if not node_ids:
        raise InvalidParameterError(f"--eds {eds[0]}: give --node N, the node-ID of the drive")
    if len(eds) not in (1, len(node_ids)):
        raise InvalidParameterError(
            f"{len(eds)} --eds for {len(node_ids)} --node: give one --eds per --node, or one for all"
        )
    pairs = [(eds[0] if len(eds) == 1 else eds[i], node) for i, node in enumerate(node_ids)]
    if args.load_node is not None:
        pairs.append((args.load_eds or eds[0], args.load_node))
    elif args.load_eds is not None:
        raise InvalidParameterError("--load-eds is the dictionary of --load-node: give --load-node too")
    from ..codecs.canopen import NodeMapping  # canopen loads only for dictionaries

    seen = [node for _, node in pairs]
    twice = sorted({node for node in seen if seen.count(node) > 1})
    if twice:
        raise InvalidParameterError(f"node-ID {twice[0]} given twice: one --node per drive")
    return [NodeMapping.read(path, node) for path, node in pairs]


def _canopen_named(summary: FileSummary, nodes: list[NodeMapping]) -> FileSummary:
    """The CAN IDs named by the CANopen dictionaries: SYNC, each TPDO with its objects, the predefined services."""
    from ..codecs.canopen import cob_id_names, service_name
    from ..errors import InvalidParameterError

    if summary.kind != "can":
        raise InvalidParameterError(
            f"{summary.path}: --eds names the frames of a CAN log, and this is a {summary.kind} file"
        )
    names = cob_id_names(nodes)

    def name(info: CanIdInfo) -> str | None:
        return info.message if info.extended else names.get(info.can_id) or service_name(info.can_id) or info.message

    return replace(summary, can_ids=[replace(i, message=name(i)) for i in summary.can_ids])


def _number(value: float | None) -> str:
    return "" if value is None else f"{value:g}"

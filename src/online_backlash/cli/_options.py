"""The command-line options shared by several subcommands, each declared once with its one type, and the
reader options built from them (no math here)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from ..errors import InvalidParameterError

if TYPE_CHECKING:
    from ..codecs.options import CanDecoding, ReaderOption


def log_formats(inspected: bool = False) -> str:
    """The formats a log may be in (the help of a LOG argument), from the one table
    (:data:`~online_backlash.replay.registry.FORMATS`); ``inspected``: those ``inspect`` describes."""
    from ..replay.registry import FORMATS

    return "; ".join(f.help_text() for f in FORMATS if f.describe is not None or not inspected)


def add_store_option(parser: argparse._ActionsContainer) -> None:
    """``--db DB``: the history store (``track``, ``history``, ``serve``, ``opcua``)."""
    parser.add_argument(
        "--db", required=True, help="history store: an SQLite file path or postgresql://user@host/dbname"
    )


def add_max_age_option(parser: argparse._ActionsContainer) -> None:
    """``--max-age-h H``: when a gearbox's state becomes unknown (``history``, ``serve``, ``opcua``)."""
    parser.add_argument(
        "--max-age-h",
        type=float,
        default=168.0,
        metavar="H",
        help="a gearbox's state is unknown when its latest observable estimate is older than H calendar hours",
    )


def add_play_level_options(group: argparse._ActionsContainer, limit_help: str, warn_help: str) -> None:
    """``--limit-arcmin X --warn-arcmin X``: the play's limit and warning level, arcmin (``track`` stores them with the
    gearbox, ``listen`` publishes the state against them, ``history`` forecasts against them)."""
    group.add_argument("--limit-arcmin", type=float, metavar="X", help=limit_help)
    group.add_argument("--warn-arcmin", type=float, metavar="X", help=warn_help)


def add_log_options(parser: argparse.ArgumentParser) -> None:
    """Options that say how to read a recorded log: columns, units, counts per revolution."""
    group = parser.add_argument_group("log format")
    group.add_argument(
        "--columns",
        metavar="MAP",
        help="map the log's column names, e.g. time=time_s,motor=motor_counts,load=spindle_counts[,torque=T]",
    )
    add_units_option(group)
    add_counts_options(group)
    group.add_argument("--skip-bad-rows", action="store_true", help="count and skip malformed rows instead of stopping")
    add_csv_dialect_options(group)


def add_units_option(group: argparse._ActionsContainer) -> None:
    """``--units U``: the unit of the motor and load angles (:class:`~online_backlash.replay.options.Units`,
    ``CanDecoding.units``), declared once for the logs and ``listen can``."""
    group.add_argument(
        "--units",
        choices=("deg", "rad", "rev", "arcmin", "counts"),
        help="unit of the motor and load columns or DBC signals (default: deg for CSV; a measurement file's channel "
        "units; the DBC signals' units)",
    )


def add_period_option(group: argparse._ActionsContainer) -> None:
    """``--period S``: the nominal sample period (:class:`~online_backlash.codecs.options.Timing`), declared once for
    the logs of ``estimate``, ``diagnose`` and ``track`` and the live sources of ``listen`` and ``track --listen``.
    A value that is not a positive number is argparse's usage error (exit 2), as every option's bad value."""
    group.add_argument(
        "--period",
        type=positive_float,
        metavar="S",
        help="nominal sample period, seconds, for gap detection (CSV, CAN log or bus, serial capture or port); learnt "
        "if not given. With a frame counter (CAN, serial, CANopen), sample times are then first time + counter "
        "periods x S, not the jittery timestamps",
    )


def add_serial_format_option(
    group: argparse._ActionsContainer, flag: str = "--serial-format", required: bool = False
) -> None:
    """``--serial-format ascii|binary`` (``listen serial``: ``--format``, required): how a serial capture's or port's
    bytes are framed (:class:`~online_backlash.codecs.options.SerialFraming`)."""
    from ..codecs.options import SERIAL_FORMATS

    group.add_argument(
        flag,
        dest="serial_format",
        choices=SERIAL_FORMATS,
        help="frame format of a serial capture (.serial) or port: 'ascii' lines time,motor,load (s, deg, deg) or "
        "'binary' COBS frames with CRC-16",
        required=required,
    )


def add_estimator_options(group: argparse._ActionsContainer, new_gearbox: bool = False) -> None:
    """``--memory-reversals N [--memory-s S] --sample-period S``: the recursive estimator's memory and sampling period,
    seconds; ``new_gearbox`` (``track``): a new gearbox's, without defaults (a gearbox already tracked keeps its own;
    no ``--memory-s``)."""
    if new_gearbox:
        memory = ("memory of a new gearbox's estimator, in reversals (shorter follows fast wear with less lag, more "
                  "noise); default: BacklashRLS's")  # fmt: skip
        period = "sampling period of a new gearbox's logs, seconds; default: BacklashRLS's (0.001)"
    else:
        memory, period = "memory of the estimator, in reversals", "sampling period of the log or source, seconds"
    defaults = (None, None) if new_gearbox else (10.0, 0.001)
    group.add_argument("--memory-reversals", type=positive_float, default=defaults[0], metavar="N", help=memory)
    if not new_gearbox:
        group.add_argument(
            "--memory-s",
            type=positive_float,
            metavar="S",
            help="memory in seconds of motion (instead of / besides reversals)",
        )
    group.add_argument("--sample-period", type=positive_float, default=defaults[1], metavar="S", help=period)


def add_can_bus_options(group: argparse._ActionsContainer, required: bool) -> None:
    """``--interface I --channel C --bitrate B --raw-format F``: a live CAN bus (``listen can``, ``track --listen
    can``)."""
    from ..drivers.live import CAN_RAW_FORMATS

    group.add_argument(
        "--interface", required=required, help="python-can interface: socketcan, pcan, kvaser, vector, virtual, ..."
    )
    group.add_argument("--channel", required=required, help="channel of the interface, e.g. can0")
    group.add_argument("--bitrate", type=int, help="bit rate, bit/s (where the interface sets it)")
    group.add_argument("--raw-format", choices=CAN_RAW_FORMATS, default="blf", help="format of the raw CAN log")


def add_serial_port_options(group: argparse._ActionsContainer, required: bool) -> None:
    """``--port URL --baud B``: a live serial port (``listen serial``, ``track --listen serial``)."""
    group.add_argument(
        "--port", required=required, help="pyserial URL: /dev/ttyUSB0, COM3, socket://host:port, loop://"
    )
    group.add_argument("--baud", type=int, default=115200, help="baud rate")


def add_live_run_options(group: argparse._ActionsContainer, raw_log_required: bool) -> None:
    """``--raw-log DIR --duration S --timeout S``: where a live source's raw capture goes and how long it runs
    (:class:`~online_backlash.drivers.live.LiveOptions`; ``track``: required with ``--listen``)."""
    group.add_argument(
        "--raw-log",
        required=raw_log_required,
        metavar="DIR",
        help="directory for the raw captures, written before decoding"
        + ("" if raw_log_required else " (required with --listen)"),
    )
    group.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds; else at Ctrl-C")
    group.add_argument("--timeout", type=positive_float, metavar="S", help="fail when nothing arrives for S seconds")


def add_counts_options(group: argparse._ActionsContainer) -> None:
    """``--motor-cpr N --load-cpr N``: encoder counts per revolution (:class:`~online_backlash.replay.options.Counts`),
    declared once for every command that reads angles in counts (a CAN decoder takes whole counts)."""
    group.add_argument(
        "--motor-cpr",
        type=positive_float,
        help="motor encoder counts per motor revolution (with --units counts; CAN: from the DBC or dictionary if not "
        "given)",
    )
    group.add_argument(
        "--load-cpr",
        type=positive_float,
        help="load encoder counts per load revolution (with --units counts; CAN: from the DBC or dictionary if not "
        "given)",
    )


def add_csv_dialect_options(group: argparse._ActionsContainer) -> None:
    """``--delimiter C --decimal M --comment C --encoding E``: override what is sniffed of a CSV or delimited text
    file (German Excel: ``--delimiter ';' --decimal ,``; a Windows export: ``--encoding cp1252``)."""
    group.add_argument(
        "--delimiter",
        type=_delimiter,
        metavar="C",
        help="CSV field separator (one character; 'tab' for a tab); default: sniffed from the file (, ; tab |)",
    )
    group.add_argument(
        "--decimal",
        choices=(".", ","),
        help="CSV decimal mark; default: sniffed (',' only with a separator other than ',')",
    )
    group.add_argument(
        "--comment",
        metavar="C",
        type=_comment,
        help="CSV lines starting with this character are comments, skipped anywhere; default: '#' lines before "
        "the header",
    )
    group.add_argument(
        "--encoding",
        metavar="NAME",
        type=_encoding,
        help="CSV text encoding, e.g. cp1252 (Windows), latin-1, utf-16; default: UTF-8, or what a byte-order "
        "mark says",
    )


def csv_dialect_options(args: argparse.Namespace) -> dict[str, str]:
    """The ``delimiter``/``decimal``/``comment``/``encoding`` keyword arguments of a CSV reader that the user gave."""
    given = {name: getattr(args, name, None) for name in ("delimiter", "decimal", "comment", "encoding")}
    return {k: v for k, v in given.items() if v is not None}


def _comment(text: str) -> str:
    from ..replay.csv import check_dialect

    return _checked(text, lambda c: check_dialect(None, None, c))[1]


def _encoding(text: str) -> str:
    from ..replay.csv import check_encoding

    return _checked(text, check_encoding)[1]


def _checked(text: str, parse: Callable[[str], Any]) -> tuple[Any, str]:
    """``(parse(text), text)``: a value parsed or checked by the library, its InvalidParameterError as argparse's
    error of the option."""
    try:
        return parse(text), text
    except InvalidParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def _delimiter(text: str) -> str:
    named = {"tab": "\t", "\\t": "\t", "semicolon": ";", "comma": ",", "pipe": "|", "space": " "}
    value = named.get(text.lower(), text)
    if len(value) != 1 or value.isalnum() or value in "\"'.+-\r\n":
        raise argparse.ArgumentTypeError(f"expected one separator character such as ',' ';' '|' or 'tab', got {text!r}")
    return value


def add_play_method_option(parser: argparse.ArgumentParser, default: str | None = "auto", new: str = "") -> None:
    """``--play-method auto|torque|kinematic``: the path of the play (issue 27; ``auto``: the data decide)."""
    parser.add_argument(
        "--play-method",
        choices=("auto", "torque", "kinematic"),
        default=default,
        help=f"path of {new}play: auto (the torque path where it fits the motion's dwells, else the kinematic "
        "play), torque (the torque's flank, a mapped torque column needed), kinematic (the motion alone, the "
        "torque left out)" + ("; default: auto" if default is None else ""),
    )


def add_ratio_option(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """``--ratio R``: motor:load gear ratio; negative for a stage that reverses direction."""
    parser.add_argument(
        "--ratio",
        type=gear_ratio,
        required=required,
        help="gear ratio motor:load (motor angle is divided by it; negative for a reversing stage)",
    )


def parse_column_map(text: str | None) -> dict[str, str] | None:
    """``"time=time_s,motor=m"`` -> ``{"time": "time_s", "motor": "m"}``."""
    if not text:
        return None
    mapping = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise InvalidParameterError(
                f"--columns expects role=column pairs such as time=time_s,motor=m,load=l; got {item!r} in {text!r}"
            )
        mapping[key.strip()] = value.strip()
    return mapping


def add_can_decoding_options(parser: argparse.ArgumentParser, required: bool) -> None:
    """``--dbc F --motor-signal S --load-signal S``: how CAN frames carry the two angles."""
    group = parser.add_argument_group("CAN decoding")
    group.add_argument(
        "--dbc",
        required=required,
        metavar="FILE",
        help="DBC describing the frames; 'rig' for the example rig.dbc shipped with the package",
    )
    group.add_argument(
        "--motor-signal",
        required=required,
        metavar="MSG.SIGNAL",
        help="motor angle (counts, deg, rad...), e.g. MotorAngle.Count",
    )
    group.add_argument(
        "--load-signal",
        required=required,
        metavar="MSG.SIGNAL",
        help="load angle (counts, deg, rad...), e.g. LoadAngle.Count",
    )
    group.add_argument(
        "--wrap-deg",
        type=wrap_deg_type,
        metavar="DEG",
        help="angle signals (deg, rad...) wrap every DEG degrees, e.g. 360, or per signal: motor=360,load=none; "
        "default: multi-turn as given",
    )
    group.add_argument(
        "--counter-signal",
        default="Counter",
        metavar="NAME",
        help="rolling counter signal in those messages ('none': pair by time)",
    )
    group.add_argument(
        "--checksum-signal",
        default="Checksum",
        metavar="NAME",
        help="CRC-8/SAE-J1850 checksum byte in those messages ('none': no check)",
    )
    group.add_argument(
        "--max-skew",
        type=positive_float,
        metavar="S",
        help="pairing by time (no counter signal; event-driven CANopen TPDOs): "
        "the largest time between the motor's and the load's frame of one sample, seconds (default 1 ms)",
    )
    add_canopen_options(parser)


def add_canopen_options(parser: argparse.ArgumentParser) -> None:
    """``--eds F --node N [--load-node N [--load-eds F] | --load-subindex K]``: CANopen drives instead of a DBC."""
    group = parser.add_argument_group("CANopen drives (instead of --dbc)")
    group.add_argument(
        "--eds",
        metavar="FILE",
        help="EDS or DCF of the motor drive: its TPDO mapping carries position actual value 0x6064",
    )
    group.add_argument("--node", type=node_id_type, metavar="N", help="node-ID of the motor drive (1-127)")
    group.add_argument(
        "--load-node",
        type=node_id_type,
        metavar="N",
        help="load encoder: 0x6064 of this node; default: 0x60E4 of --node",
    )
    group.add_argument("--load-eds", metavar="FILE", help="EDS or DCF of --load-node, if it is not the --eds one")
    group.add_argument(
        "--load-subindex",
        type=subindex_type,
        metavar="K",
        help="sub-index of 0x60E4 (additional position actual value); default: the first mapped",
    )


def can_decoding(args: argparse.Namespace) -> CanDecoding:
    """How CAN frames become angles, from :func:`add_can_decoding_options` (and :func:`add_canopen_options`)."""
    from ..codecs.dbc import RIG_DBC
    from ..codecs.options import CanDecoding, Canopen

    def optional(name: str) -> str | None:
        return None if name.lower() == "none" else name

    skew = {} if args.max_skew is None else {"max_skew_s": args.max_skew}  # None: the pairing's own default
    if getattr(args, "eds", None) is not None:
        if args.node is None:
            raise InvalidParameterError(f"--eds {args.eds}: give --node N, the node-ID of the motor drive")
        if getattr(args, "dbc", None) is not None:
            raise InvalidParameterError("--dbc and --eds both given: a CAN log is decoded with one of them")
        where = Canopen(args.eds, args.node, args.load_node, args.load_eds, args.load_subindex)
        return CanDecoding(canopen=where, **skew)
    return CanDecoding(
        RIG_DBC if args.dbc == "rig" else args.dbc,
        args.motor_signal,
        args.load_signal,
        optional(args.counter_signal),
        optional(args.checksum_signal),
        getattr(args, "units", None),
        args.wrap_deg,
        **skew,
    )


def reader_options(args: argparse.Namespace, types: Iterable[type[ReaderOption]]) -> list[ReaderOption]:
    """The reader options of ``types`` (those a log's format takes, :class:`~online_backlash.replay.formats.LogFormat`)
    from the log-format arguments; each option is built only when asked for (a CSV's map is parsed for a CSV)."""
    from ..replay import options as o

    builders: dict[type[ReaderOption], Callable[[], ReaderOption]] = {
        o.Columns: lambda: o.Columns(parse_column_map(args.columns)),
        o.Units: lambda: o.Units(args.units),
        o.Counts: lambda: o.Counts(args.motor_cpr, args.load_cpr),
        o.WholeCounts: lambda: o.WholeCounts(args.motor_cpr, args.load_cpr),
        o.BadRows: lambda: o.BadRows(args.skip_bad_rows),
        o.Pace: lambda: o.Pace(getattr(args, "realtime", False)),
        o.Timing: lambda: o.Timing(getattr(args, "period", None)),
        o.CsvDialect: lambda: o.CsvDialect(**csv_dialect_options(args)),
        o.SerialFraming: lambda: o.SerialFraming(args.serial_format),
        o.CanDecoding: lambda: can_decoding(args),
    }
    return [builders[t]() for t in types]


def _integer_in(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an integer ``low..high`` (decimal or 0x hex)."""

    def parse(text: str) -> int:
        try:
            value = int(text, 0)
        except ValueError:
            value = low - 1
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected a number {low}..{high}, got {text!r}")
        return value

    return parse


#: argparse type of a CANopen node-ID (1..127).
node_id_type = _integer_in(1, 127)


#: argparse type of a CANopen object's sub-index (1..254).
subindex_type = _integer_in(1, 254)
#: argparse type of a TCP port (0: any free one).
port_type = _integer_in(0, 65535)


def wrap_deg_type(text: str) -> Any:
    """argparse type of ``--wrap-deg``: ``DEG`` or ``motor=DEG,load=DEG``
    (:func:`~online_backlash.codecs.dbc.parse_wrap_deg`)."""
    from ..codecs.dbc import parse_wrap_deg

    return _checked(text, parse_wrap_deg)[0]


def positive_float(text: str) -> float:
    """argparse type of options that must be finite and positive, e.g. ``--every`` seconds."""
    value = _float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    """argparse type of options that must be finite and zero or more, e.g. ``--bridge-s`` seconds."""
    value = _float(text)
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


#: argparse type of a count that may be 0 (``--max-terms``).
count_type = _integer_in(0, 10**9)


def gear_ratio(text: str) -> float:
    """argparse type of a gear ratio motor:load (negative for a reversing stage): a finite, non-zero number
    whose magnitude is within :data:`~online_backlash.stream.RATIO_LIMITS`."""
    from ..stream import RATIO_LIMITS, check_ratio

    try:
        return check_ratio(_float(text))
    except InvalidParameterError:
        low, high = RATIO_LIMITS
        raise argparse.ArgumentTypeError(
            f"expected a finite non-zero number, a gear ratio motor:load with {low:g} <= |R| <= {high:g}; got {text!r}"
        ) from None


def nonempty_text(text: str) -> str:
    """argparse type of a name that must not be empty or blank (a gearbox id)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a non-empty name")
    return text


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan

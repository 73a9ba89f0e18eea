"""Options and output helpers shared by several subcommands (no math here)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any


def add_log_options(parser: argparse.ArgumentParser) -> None:
    """Options that say how to read a recorded log: columns, units, counts per revolution."""
    group = parser.add_argument_group("log format")
    group.add_argument(
        "--columns",
        metavar="MAP",
        help="map the log's column names, e.g. time=time_s,motor=motor_counts,load=spindle_counts[,torque=T]",
    )
    group.add_argument(
        "--units",
        choices=("deg", "rad", "rev", "arcmin", "counts"),
        help="unit of the motor and load columns or DBC signals (default: deg for CSV; a measurement file's channel units; the DBC signals' units)",
    )
    group.add_argument("--motor-cpr", type=float, help="motor encoder counts per motor revolution (with --units counts)")
    group.add_argument("--load-cpr", type=float, help="load encoder counts per load revolution (with --units counts)")
    group.add_argument("--skip-bad-rows", action="store_true", help="count and skip malformed rows instead of stopping")


def add_ratio_option(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """``--ratio R``: motor:load gear ratio; negative for a stage that reverses direction."""
    parser.add_argument(
        "--ratio",
        type=float,
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
            raise argparse.ArgumentTypeError(f"--columns expects name=column pairs, got {item!r}")
        mapping[key.strip()] = value.strip()
    return mapping


def print_json(obj: dict[str, Any]) -> None:
    """Print one JSON object on stdout (NaN and infinities become null)."""

    def clean(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        return value

    json.dump(clean(obj), sys.stdout, indent=2, sort_keys=False)
    sys.stdout.write("\n")


def add_can_decoding_options(parser: argparse.ArgumentParser, required: bool) -> None:
    """``--dbc F --motor-signal S --load-signal S``: how CAN frames carry the two angles."""
    group = parser.add_argument_group("CAN decoding")
    group.add_argument("--dbc", required=required, metavar="FILE", help="DBC describing the frames; 'rig' for the example rig.dbc shipped with the package")
    group.add_argument("--motor-signal", required=required, metavar="MSG.SIGNAL", help="motor angle (counts, deg, rad...), e.g. MotorAngle.Count")
    group.add_argument("--load-signal", required=required, metavar="MSG.SIGNAL", help="load angle (counts, deg, rad...), e.g. LoadAngle.Count")
    group.add_argument(
        "--wrap-deg", type=_positive_float, metavar="DEG", help="angle signals (deg, rad...) wrap every DEG degrees, e.g. 360; default: multi-turn as given"
    )
    group.add_argument("--counter-signal", default="Counter", metavar="NAME", help="rolling counter signal in those messages ('none': pair by time)")
    group.add_argument("--checksum-signal", default="Checksum", metavar="NAME", help="CRC-8/SAE-J1850 checksum byte in those messages ('none': no check)")


def can_decoding_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of the CAN sources (``CanSource``, ``CanLog``) from :func:`add_can_decoding_options`."""
    from ..codecs.dbc import RIG_DBC

    def optional(name: str) -> str | None:
        return None if name.lower() == "none" else name

    return {
        "dbc": RIG_DBC if args.dbc == "rig" else args.dbc,
        "motor_signal": args.motor_signal,
        "load_signal": args.load_signal,
        "counter_signal": optional(args.counter_signal),
        "checksum_signal": optional(args.checksum_signal),
        "units": getattr(args, "units", None),
        "wrap_deg": args.wrap_deg,
    }


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value

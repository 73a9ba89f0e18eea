"""Command-line interface: ``online-backlash <subcommand> ...``.

One module per subcommand in this package (cantools style). Each module defines
``add_subparser(subparsers)`` which registers its parser and sets ``func`` to a function
``func(args) -> int``. The CLI does no math: it parses options, calls the library, prints.
Errors print as one line ``error: FILE[:LINE]: reason`` with a non-zero exit and never a traceback
(``--debug``, before or after the subcommand, shows it); see :func:`._output.run_command`.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from ._output import run_command


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand module of this package registered."""
    parser = argparse.ArgumentParser(
        prog="online-backlash",
        description="Identify gearbox backlash from motor and load encoders, online or from logs.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--debug", action="store_true", help="show the full traceback on errors")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.add_subparser(subparsers)
    for subparser in subparsers.choices.values():  # --debug after the subcommand too
        with contextlib.suppress(argparse.ArgumentError):  # a subcommand that declares its own keeps it
            subparser.add_argument(
                "--debug", action="store_true", default=argparse.SUPPRESS, help="show the full traceback on errors"
            )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``online-backlash`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    return run_command(args.func, args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

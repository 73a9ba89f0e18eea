"""How a command ends: its exit codes, the one-line errors and warnings on stderr, the report printed."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from collections.abc import Callable
from typing import Any

from ..errors import BacklashError, BacklashWarning, InvalidParameterError, NotExcitedError

#: Exit code of a command that failed (argparse uses 2 for bad options, an interrupt 130).
EXIT_ERROR = 1


#: Exit code of a report without a play figure (the data do not show the play, or the fit gave no number):
#: the report is printed, the reason goes to stderr, and a script never takes a missing play for a result.
EXIT_NO_PLAY = 3


def run_command(func: Callable[[argparse.Namespace], int | None], args: argparse.Namespace) -> int:
    """``func(args)`` with every failure as one line ``error: FILE[:LINE]: reason`` on stderr and a non-zero exit.

    No traceback reaches the user (``--debug`` shows it): the library's errors name their file or
    setting; an OSError names its file; anything else is reported as unexpected, with its type.
    The library's warnings (:class:`~online_backlash.errors.BacklashWarning`) print as one line
    ``warning: ...`` each.
    """
    debug = getattr(args, "debug", False)
    with warnings.catch_warnings():
        warnings.simplefilter("always", BacklashWarning)
        warnings.showwarning = _show_warning
        try:
            return int(func(args) or 0)
        except KeyboardInterrupt:
            print("error: interrupted", file=sys.stderr)
            return 130
        except Exception as exc:
            if debug:
                raise
            print(f"error: {error_line(exc, getattr(args, 'log', None))}", file=sys.stderr)
            return EXIT_ERROR


def error_line(exc: BaseException, log: str | None = None) -> str:
    """The one-line description of an error, without the ``error:`` prefix; data that cannot
    identify the model (NotExcitedError) are named by the ``log`` they came from."""
    if isinstance(exc, NotExcitedError) and log is not None:
        text = f"{log}: {exc}"
    elif isinstance(exc, (BacklashError, argparse.ArgumentTypeError)):
        text = str(exc)
    elif isinstance(exc, OSError) and exc.filename is not None:
        reason = "no such file or folder" if isinstance(exc, FileNotFoundError) else exc.strerror or str(exc)
        text = f"{exc.filename}: {reason}"
    elif isinstance(exc, OSError):
        text = exc.strerror or str(exc)
    elif isinstance(exc, ImportError) and exc.name:
        text = f"module {exc.name!r} is not installed ({exc})"
    else:
        text = f"unexpected {type(exc).__name__}: {exc} (run with --debug for the trace, and please report it)"
    return " ".join(text.split())  # one line


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: Any = None,
    line: str | None = None,
) -> None:
    """``warnings.showwarning`` of the CLI: one line ``warning: ...`` on stderr (another library's warning
    with its category, e.g. ``warning: RuntimeWarning: ...``), never the source line of a traceback."""
    text = " ".join(str(message).split())
    if not issubclass(category, BacklashWarning):
        text = f"{category.__name__}: {text}"
    print(f"warning: {text}", file=sys.stderr)


def warn_if_implausible(note: str | None, source: str) -> None:
    """Print one line ``warning: SOURCE: note`` on stderr when a fit's plausibility check
    (:func:`~online_backlash.log_fit.plausibility`) found likely wrong units or ratio."""
    if note is not None:
        print(f"warning: {source}: {note}", file=sys.stderr)


def play_exit_code(play_deg: float, source: str, reason: str | None = None) -> int:
    """The exit code of a command that printed a play: 0 for a finite ``play_deg``; else one line
    ``error: SOURCE: no play: reason`` on stderr and :data:`EXIT_NO_PLAY` (never exit 0 with a NaN play)."""
    if math.isfinite(play_deg):
        return 0
    why = reason or "the fit gave no finite play: check the units (--units, --motor-cpr/--load-cpr) and --ratio"
    print(f"error: {source}: no play: {why}", file=sys.stderr)
    return EXIT_NO_PLAY


def files_written(args: argparse.Namespace) -> dict[str, str]:
    """What a command wrote besides its report: ``--plot``, ``--trace`` and ``--report`` files, kind -> path
    (printed after a text report, so a user knows where to look)."""
    return {kind: getattr(args, kind) for kind in ("plot", "trace", "report") if getattr(args, kind, None)}


def print_report(text_or_json: str | dict[str, Any], written: dict[str, str]) -> None:
    """Print a command's report (a text, or a dict as one JSON object, whose reader gave the paths) and, after
    a text, one line per file written: ``plot:           FILE``."""
    if isinstance(text_or_json, dict):
        print_json(text_or_json)
        return
    print(text_or_json)
    for kind, path in written.items():
        print(f"{kind + ':':<16}{path}")


def check_plot_path(path: str | None) -> None:
    """Refuse, before any work, a ``--plot`` file whose suffix matplotlib cannot write (no suffix: PNG)."""
    if path is None:
        return
    from matplotlib.backend_bases import FigureCanvasBase

    suffix = os.path.splitext(path)[1].lower().lstrip(".")
    formats = FigureCanvasBase.get_supported_filetypes()
    if suffix and suffix not in formats:
        raise InvalidParameterError(
            f"{path}: cannot draw a plot as .{suffix}; use one of {', '.join('.' + f for f in sorted(formats))}"
        )


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

"""Opening live sources from parsed options, and Ctrl-C handling (shared by ``listen`` and ``track``)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from ..codecs.options import Counts, FrameRules, WholeCounts
from ..drivers.live import LiveOptions, LiveSource
from ..errors import InvalidParameterError
from ._options import can_decoding


def open_can_source(args: argparse.Namespace) -> LiveSource:
    """A :class:`~online_backlash.drivers.can.CanSource` (``--dbc``) or
    :class:`~online_backlash.drivers.canopen.CanopenSource`
    (``--eds``) from the options of ``listen can``."""
    from ..drivers.can import CanSource, open_bus

    decoding = can_decoding(args)
    source: type[CanSource] = CanSource
    if decoding.canopen is not None:
        from ..drivers.canopen import CanopenSource

        source = CanopenSource
    elif not (args.dbc and args.motor_signal and args.load_signal):
        raise InvalidParameterError(
            "listen can decodes frames with --dbc FILE --motor-signal S --load-signal S, or with --eds FILE --node N "
            "(CANopen)"
        )
    counts = WholeCounts(args.motor_cpr, args.load_cpr)  # a DBC's or dictionary's counts are whole
    live = _live_options(args, args.raw_format)
    bus = open_bus(args.interface, args.channel, args.bitrate)
    return source(bus, decoding, counts=counts, frames=FrameRules(args.period), live=live)


def open_serial_source(args: argparse.Namespace) -> LiveSource:
    """A :class:`~online_backlash.drivers.serial.SerialSource` from the options of ``listen serial``."""
    from ..drivers.serial import SerialSource

    counts = Counts(args.motor_cpr, args.load_cpr)
    frames = FrameRules(args.period)
    return SerialSource(
        args.port, args.baud, args.serial_format, counts=counts, frames=frames, live=_live_options(args)
    )


def _live_options(args: argparse.Namespace, raw_format: str = "blf") -> LiveOptions:
    """The options every live source takes: raw capture, duration, timeout."""
    if os.path.exists(args.raw_log) and not os.path.isdir(args.raw_log):
        raise InvalidParameterError(f"--raw-log {args.raw_log}: is a file; the raw captures go into a folder")
    return LiveOptions(args.raw_log, raw_format, args.duration, args.timeout)


#: The end of the line :func:`ctrl_c_ends_the_run` writes on stderr once Ctrl-C is handled.
CTRL_C_READY = "Ctrl-C ends the run with its summary"


@contextmanager
def ctrl_c_ends_the_run(stop: Callable[[], None], label: str) -> Iterator[None]:
    """Within the block, Ctrl-C calls ``stop`` (the run ends gracefully, with its summary); the handler
    is installed before the line ``LABEL: listening; Ctrl-C ends the run with its summary`` goes to
    stderr, so whoever waits for that line (a user, a test) may press Ctrl-C from then on. Off the main
    thread Python cannot handle signals: no handler, no line."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, lambda *_: stop())
    try:
        print(f"{label}: listening; {CTRL_C_READY}", file=sys.stderr, flush=True)
        yield
    finally:
        signal.signal(signal.SIGINT, previous)

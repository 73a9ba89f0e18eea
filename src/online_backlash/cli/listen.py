"""``online-backlash listen can|serial ...``: estimate the backlash live from a rig.

Every frame or byte received is written to ``--raw-log DIR`` before it is decoded, so
``online-backlash estimate DIR`` (the whole directory, or one of its files) gives the same
result later. Once Ctrl-C is handled, a line on stderr says so (``SOURCE: listening; Ctrl-C ends the
run with its summary``); then a status line shows the estimate with its standard error, the samples it
has learned, samples/s, corrupt frames and gaps. The summary comes when ``--duration`` is reached or on
Ctrl-C, after everything read by then is learned (on CAN, also the frames still waiting on the bus);
with ``--json`` it is one JSON object on stdout, the keys of ``estimate --json`` and the source's counters. With
``--mqtt
mqtt://HOST:PORT/PREFIX --gearbox ID`` every estimate is also published (:mod:`online_backlash.publish`).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from ..errors import LogFormatError, SourceError
from ..log_fit import fit_recursive, report_text
from ..output_columns import EstimateRow, arcmin
from ._live import ctrl_c_ends_the_run, open_can_source, open_serial_source
from ._mqtt import add_listen_mqtt_options, mqtt_publisher, mqtt_summary_line, mqtt_tls, row_sink
from ._options import (
    add_can_bus_options,
    add_can_decoding_options,
    add_counts_options,
    add_estimator_options,
    add_live_run_options,
    add_period_option,
    add_ratio_option,
    add_serial_format_option,
    add_serial_port_options,
    add_units_option,
    positive_float,
)
from ._output import play_exit_code, print_json


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "listen",
        help="estimate live from a CAN bus or a serial port",
        description="Estimate the backlash live from a CAN bus (python-can + a DBC) or a serial port (pyserial).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    sources = parser.add_subparsers(dest="source_kind", metavar="SOURCE", required=True)

    can_parser = sources.add_parser(
        "can",
        help="a CAN bus (any python-can interface)",
        description="Listen to a CAN bus; frames are decoded with a DBC (--dbc) or a CANopen drive's EDS/DCF (--eds "
        "--node).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add_can_bus_options(can_parser, required=True)
    add_can_decoding_options(can_parser, required=False)  # --dbc with its signals, or --eds --node: checked on opening
    add_counts_options(can_parser)
    add_units_option(can_parser)
    _add_common(can_parser)
    can_parser.set_defaults(func=run, open_source=open_can_source)

    serial_parser = sources.add_parser(
        "serial",
        help="a serial port (pyserial URL)",
        description="Listen to a serial port: 'ascii' lines time,motor,load (s, deg, deg) or 'binary' COBS frames with "
        "CRC-16.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add_serial_port_options(serial_parser, required=True)
    add_serial_format_option(serial_parser, "--format", required=True)
    add_counts_options(serial_parser)
    _add_common(serial_parser)
    serial_parser.set_defaults(func=run, open_source=open_serial_source)


def _add_common(parser: argparse.ArgumentParser) -> None:
    add_ratio_option(parser)
    add_live_run_options(parser, raw_log_required=True)
    add_period_option(parser)
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object on stdout")
    parser.add_argument(
        "--status-every", type=positive_float, default=0.5, metavar="S", help="seconds of data between status lines"
    )
    add_estimator_options(parser.add_argument_group("recursive estimator"))
    add_listen_mqtt_options(parser)


class _StatusLine:
    """The live status line on stderr, fed by the pipeline's rows (``fit_recursive``'s trace)."""

    def __init__(self, counters: Any) -> None:
        self.counters = counters
        self.start = self._last = time.monotonic()
        self._last_samples = 0
        self.shown = False

    def __call__(self, row: EstimateRow) -> None:
        now = time.monotonic()
        c = self.counters
        rate = (c.samples - self._last_samples) / max(now - self._last, 1e-9)
        self._last, self._last_samples = now, c.samples
        text = (
            f"{now - self.start:7.1f} s  backlash {arcmin(row.backlash_deg):8.3f}"
            f" ± {arcmin(row.backlash_std_deg):.3f} arcmin  {row.n_samples} samples, {rate:7.0f} samples/s"
            f"  corrupt {c.corrupt}  gaps {c.gaps}"
        )
        sys.stderr.write("\r" + text + "\x1b[K")
        sys.stderr.flush()
        self.shown = True

    def end(self) -> None:
        if self.shown:
            sys.stderr.write("\n")


def run(args: argparse.Namespace) -> int:
    label = f"{args.source_kind} {getattr(args, 'channel', None) or getattr(args, 'port', '')}"
    params = {
        "memory_reversals": args.memory_reversals,
        "memory_s": args.memory_s,
        "sample_period_s": args.sample_period,
    }
    started = time.monotonic()
    every_s = args.status_every if args.every is None else args.every
    with (
        mqtt_publisher(args.mqtt, args.gearbox, args.warn_arcmin, args.limit_arcmin, mqtt_tls(args)) as publisher,
        args.open_source(args) as source,
    ):
        status = _StatusLine(source.counters)
        try:
            with ctrl_c_ends_the_run(source.request_stop, label):
                trace = row_sink(publisher, status)
                chunks = source.iter_chunks()
                report, _ = fit_recursive(chunks, args.ratio, every_s=every_s, trace=trace, source=label, **params)
        except LogFormatError as exc:
            if source.counters.samples:
                raise
            raise SourceError(f"{label}: no samples received ({_counts(source.counters.as_dict())})") from exc
        finally:
            status.end()
    summary = report.as_dict()
    summary.update(source.counters.as_dict())
    summary["duration_s"] = time.monotonic() - started
    summary["raw_log"] = args.raw_log
    pipeline = getattr(source, "pipeline", None)
    if pipeline is not None and pipeline.frames_per_sample == 2:
        summary["pair_skew_mean_s"] = pipeline.skew_mean_s
        summary["pair_skew_max_s"] = pipeline.skew_max_s
    if publisher is not None:
        summary.update(publisher.counts())
    if args.json:
        print_json(summary)
    else:
        print(report_text(report, label))
        print(
            f"received:       {_counts(source.counters.as_dict())} in {summary['duration_s']:.1f} s; raw log in "
            f"{args.raw_log}"
        )
        if publisher is not None:
            print(mqtt_summary_line(publisher))
    return play_exit_code(report.backlash_deg, label, report.no_play_reason())


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items())

"""``--mqtt mqtt://HOST:PORT/PREFIX`` for ``listen`` and ``track --listen``: options and the publisher."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from ..errors import InvalidParameterError
from ._options import add_play_level_options

if TYPE_CHECKING:
    from ..history.store import HistoryStore
    from ..output_columns import EstimateRow
    from ..publish import MqttPublisher, MqttTarget, MqttTls

MQTT_HELP = (
    "publish every estimate as JSON to PREFIX/GEARBOX/estimate and the alarm state, retained, to PREFIX/GEARBOX/state "
    "(a broker that goes away is reconnected to; estimates meanwhile are dropped and counted)"
)


def add_mqtt_option(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--mqtt URL`` and its TLS files (``track`` has ``--gearbox``, ``--every`` and the alarm levels already)."""
    parser.add_argument("--mqtt", metavar="URL", help=MQTT_HELP)
    parser.add_argument(
        "--mqtt-ca",
        metavar="FILE",
        help="mqtts://: the CA certificate (PEM) that signed the broker's; default: the system's CAs",
    )
    parser.add_argument(
        "--mqtt-cert", metavar="FILE", help="mqtts://: a client certificate (PEM) to present to the broker"
    )
    parser.add_argument("--mqtt-key", metavar="FILE", help="mqtts://: the client certificate's private key (PEM)")


def mqtt_tls(args: argparse.Namespace) -> MqttTls:
    """The TLS files given with ``--mqtt-ca``, ``--mqtt-cert`` and ``--mqtt-key``."""
    from ..publish import MqttTls

    return MqttTls(args.mqtt_ca, args.mqtt_cert, args.mqtt_key)


def add_listen_mqtt_options(parser: argparse.ArgumentParser) -> None:
    """``--mqtt`` with what ``listen`` needs besides: the gearbox id, the interval and the alarm levels."""
    group = parser.add_argument_group("MQTT")
    add_mqtt_option(group)
    group.add_argument("--gearbox", metavar="ID", help="the gearbox's id in the topics (required with --mqtt)")
    group.add_argument(
        "--every", type=float, metavar="S", help="seconds of data between published estimates; default: --status-every"
    )
    add_play_level_options(
        group,
        "limit of the play, for the published state (without: unknown)",
        "warning level of the play, for the published state",
    )


@contextmanager
def mqtt_publisher(
    url: str | None,
    gearbox_id: str | None,
    warn_arcmin: float | None,
    limit_arcmin: float | None,
    tls: MqttTls | None = None,
    figures: Callable[[], dict[str, Any]] | None = None,
) -> Iterator[MqttPublisher | None]:
    """The running publisher for ``--mqtt URL`` (None without ``--mqtt``), closed at the end; ``figures()`` gives
    the wear figures its state messages carry (``track --listen``: :func:`history_figures`)."""
    if url is None:
        yield None
        return
    if not gearbox_id:
        raise InvalidParameterError("--mqtt publishes under the gearbox's id: give --gearbox ID")
    from ..publish import MqttPublisher, MqttTarget

    where = MqttTarget.parse(url)
    note = _connection_note(where)
    with MqttPublisher(
        url, gearbox_id, warn_arcmin, limit_arcmin, tls=tls, figures=figures, on_connection=note
    ) as publisher:
        yield publisher


def history_figures(store: HistoryStore, gearbox_id: str) -> Callable[[], dict[str, Any]]:
    """The wear figures of a gearbox's stored history as ``history`` says them, for its MQTT state message
    (none while the store holds no estimate of it)."""

    def figures() -> dict[str, Any]:
        from ..errors import BacklashError
        from ..history.report import wear_report
        from ..history.text import wear_figures

        try:
            report = wear_report(store, gearbox_id)
        except BacklashError:  # a side channel: the gearbox's first estimate may not be committed yet
            return {}
        words = wear_figures(report)
        summary = report.summary.as_dict()
        return {
            "trend_clock": summary["trend_clock"],
            "trend": words.trend_short,
            "forecast": words.forecast_short,
            "forecast_date_utc": summary["forecast_date_utc"],
        }

    return figures


def _connection_note(where: MqttTarget) -> Callable[[bool, str], None]:
    """A line on stderr whenever the broker connects, refuses or goes away (over the status line; paho's thread)."""

    def note(connected: bool, reason: str) -> None:
        what = "connected" if connected else f"connection {reason}; estimates are dropped and counted until it is back"
        sys.stderr.write(f"\r\x1b[Kmqtt: {where.host}:{where.port}: {what}\n")
        sys.stderr.flush()

    return note


def row_sink(publisher: MqttPublisher | None, then: Callable[[EstimateRow], None]) -> Callable[[EstimateRow], None]:
    """A pipeline trace callback: publish the row (placing a device clock at now, once), then ``then(row)``."""
    if publisher is None:
        return then
    from ..publish import unix_time_of

    offset: list[float | None] = [None]

    def sink(row: EstimateRow) -> None:
        time_unix_s, offset[0] = unix_time_of(row.time_s, offset[0])
        publisher.publish(row, time_unix_s)
        then(row)

    return sink


def mqtt_summary_line(publisher: MqttPublisher) -> str:
    """The summary's MQTT line: published, dropped, connections."""
    c = publisher.counts()
    return (
        f"mqtt:           {c['mqtt_published']} estimates published, {c['mqtt_dropped']} dropped while the broker was "
        "away, "
        f"{c['mqtt_connections']} connections to {publisher.target.host}:{publisher.target.port}"
    )

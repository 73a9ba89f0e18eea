"""Live estimates over MQTT: ``listen`` and ``track --listen`` with ``--mqtt mqtt://HOST:PORT/PREFIX``.

Every estimate the pipeline emits (every ``--every`` seconds of *data*) goes, as one JSON
object, to ``PREFIX/GEARBOX/estimate``: the keys of ``estimate --json``
(:data:`~online_backlash.output_columns.REPORT_KEYS`, ``samples`` counting every sample the estimator
learned) plus ``backlash_std_deg``, ``n_reversals``, ``time`` (ISO 8601, UTC), ``time_unix_s``,
``gearbox`` and ``state``. The alarm state (:func:`online_backlash.history.alarms.evaluate_alarm`
applied to the latest estimate, with the gearbox's warning level and limit in arcmin:
``ok | warning | alarm | unknown``; ``unknown`` without a limit, or while the play is not
observable) goes to ``PREFIX/GEARBOX/state``, *retained*, whenever it changes, and again after
every (re)connection (``track --listen`` adds the wear figures of the gearbox's history as
``history`` says them, read when the state changes: ``trend_clock``, ``trend``, ``forecast``,
``forecast_date_utc``), so a subscriber that arrives later, or a broker that restarted without
persistence, has it. Whether the publisher is there at all goes, retained, to
``PREFIX/GEARBOX/status``: ``online`` on every connection, ``offline`` when it stops, and
``offline`` as the client's *last will*, which the broker publishes when the connection is lost
without a goodbye (the host died, the network went) -- so a dashboard never shows a stale
state as if it were live (the Homie convention's ``$state``; MQTT 3.1.1 section 3.1.2.5).

``mqtts://HOST[:PORT]/PREFIX`` (port 8883 by default) connects over TLS, checking the broker's
certificate against the system's CAs or ``--mqtt-ca FILE``; ``--mqtt-cert``/``--mqtt-key``
present a client certificate. A user name in the URL (``mqtt://USER@HOST/PREFIX``) logs in, with
the password from the environment variable :data:`PASSWORD_ENV` (not from the command line, where
other users of the machine could read it).

The broker is a side channel: the estimate and the raw capture never wait for it. The client
(paho-mqtt 2.x) runs its network loop in its own thread and reconnects by itself (1 s, doubling
to 30 s); an estimate due while it is not connected is *dropped and counted*
(:attr:`MqttPublisher.dropped`), never queued, and paho's own queue is bounded too. A state
change while disconnected waits in one slot (the newest state) and goes out on reconnection.

This module sits above :mod:`online_backlash.output_columns` and :mod:`online_backlash.pipeline` (it
publishes their rows) and below the CLI; drivers, replay, codecs and history never import it.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import threading
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from .errors import InvalidParameterError
from .history.alarms import AlarmStatus, check_alarm_levels, evaluate_alarm
from .output_columns import ARCMIN_PER_DEG, REPORT_KEYS, EstimateRow, select
from .stream import live_clock_offset

#: Default MQTT port (unencrypted).
DEFAULT_PORT = 1883

#: Default MQTT port over TLS (``mqtts://``).
DEFAULT_TLS_PORT = 8883

#: The environment variable holding the broker password for a user named in the URL.
PASSWORD_ENV = "ONLINE_BACKLASH_MQTT_PASSWORD"

#: Bound of paho's outgoing queue (messages): a stalled connection never grows memory without bound.
MAX_QUEUED_MESSAGES = 100

#: Seconds between reconnection attempts: the first, and the most after doubling.
RECONNECT_DELAY_S = (1, 30)


@dataclass(frozen=True)
class MqttTarget:
    """Where to publish: ``mqtt[s]://[USER@]HOST[:PORT]/PREFIX`` parsed.

    Attributes
    ----------
    host : str
        Broker host name or address.
    port : int
        Broker TCP port (default :data:`DEFAULT_PORT`).
    prefix : str
        Topic prefix (may contain ``/``; no wildcards ``+`` ``#``).
    tls : bool
        ``mqtts://``: connect over TLS.
    username : str or None
        Log in as this user (password from :data:`PASSWORD_ENV`).
    """

    host: str
    port: int
    prefix: str
    tls: bool = False
    username: str | None = None

    @classmethod
    def parse(cls, url: str) -> MqttTarget:
        """Parse ``mqtt[s]://[USER@]HOST[:PORT]/PREFIX``; a malformed URL is an InvalidParameterError naming it.

        Examples
        --------
        >>> MqttTarget.parse("mqtt://broker.plant:1884/backlash/hall-3")
        MqttTarget(host='broker.plant', port=1884, prefix='backlash/hall-3', tls=False, username=None)
        >>> MqttTarget.parse("mqtts://rig@broker.plant/backlash")
        MqttTarget(host='broker.plant', port=8883, prefix='backlash', tls=True, username='rig')
        >>> MqttTarget.parse("mqtt://localhost/rig").topic("GB-7", "state")
        'rig/GB-7/state'
        """
        parts = urlsplit(url)
        tls = parts.scheme == "mqtts"
        try:
            port = (DEFAULT_TLS_PORT if tls else DEFAULT_PORT) if parts.port is None else parts.port
        except ValueError:
            port = 0
        prefix = parts.path.strip("/")
        if (
            parts.scheme not in ("mqtt", "mqtts")
            or not parts.hostname
            or port <= 0
            or not prefix
            or parts.query
            or parts.fragment
        ):
            raise InvalidParameterError(f"--mqtt: expected mqtt://HOST:PORT/PREFIX (or mqtts:// for TLS), got {url!r}")
        if parts.password is not None:
            raise InvalidParameterError(
                f"--mqtt: put the password in the environment variable {PASSWORD_ENV}, not in the URL"
            )
        if "+" in prefix or "#" in url:  # a '#' would be read as a URL fragment
            raise InvalidParameterError(f"--mqtt: the topic prefix {prefix!r} must not contain the wildcards + or #")
        return cls(parts.hostname, port, prefix, tls, parts.username or None)

    def topic(self, gearbox_id: str, leaf: str) -> str:
        """``PREFIX/GEARBOX/leaf`` (``leaf`` is ``estimate``, ``state`` or ``status``)."""
        return f"{self.prefix}/{gearbox_id}/{leaf}"


@dataclass(frozen=True)
class MqttTls:
    """TLS files for an ``mqtts://`` broker (PEM paths; None: the system's CAs, no client certificate)."""

    ca_file: str | None = None
    cert_file: str | None = None
    key_file: str | None = None


def _finite(value: Any) -> Any:
    """JSON has no NaN or infinity: such floats become None (null)."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _iso(time_unix_s: float) -> str:
    return dt.datetime.fromtimestamp(time_unix_s, dt.timezone.utc).isoformat()


def live_state(
    row: EstimateRow, time_unix_s: float, warn_arcmin: float | None, limit_arcmin: float | None
) -> AlarmStatus:
    """The alarm state of one live estimate (the latest is current: its own time is "now").

    The rules of :func:`~online_backlash.history.alarms.evaluate_alarm`: ``unknown`` without a
    limit or while the play has no finite standard deviation (not observable); ``alarm`` above
    the limit, ``warning`` above the warning level, else ``ok`` (levels in arcmin).
    """
    one = np.array
    return evaluate_alarm(
        one([time_unix_s]),
        one([row.backlash_deg]),
        one([row.backlash_std_deg]),
        warn_arcmin,
        limit_arcmin,
        now_unix_s=time_unix_s,
    )


def estimate_message(row: EstimateRow, gearbox_id: str, state: str, time_unix_s: float) -> dict[str, Any]:
    """The JSON object published to ``PREFIX/GEARBOX/estimate`` (see the module docstring).

    Angles in degrees on the load side (``backlash_arcmin`` in arc minutes), times in seconds.
    """
    values = row.values()
    report = select(REPORT_KEYS, {**values, "samples": row.n_samples, "method": "recursive"})
    extra = {"backlash_std_deg": row.backlash_std_deg, "n_reversals": row.n_reversals}
    stamp = {"time": _iso(time_unix_s), "time_unix_s": time_unix_s, "gearbox": gearbox_id, "state": state}
    return {k: _finite(v) for k, v in {**report, **extra, **stamp}.items()}


def status_message(gearbox_id: str, status: str, reason: str) -> dict[str, Any]:
    """The JSON object published, retained, to ``PREFIX/GEARBOX/status``: ``online`` or ``offline`` and why."""
    now = dt.datetime.now(dt.timezone.utc)
    return {
        "gearbox": gearbox_id,
        "status": status,
        "reason": reason,
        "time": now.isoformat(),
        "time_unix_s": now.timestamp(),
    }


def state_message(status: AlarmStatus, gearbox_id: str, time_unix_s: float) -> dict[str, Any]:
    """The JSON object published, retained, to ``PREFIX/GEARBOX/state``: state, reason, play and levels (arcmin)."""
    return {
        "gearbox": gearbox_id,
        "state": status.state,
        "reason": status.reason,
        "play_arcmin": status.play_arcmin,
        "warn_arcmin": status.warn_arcmin,
        "limit_arcmin": status.limit_arcmin,
        "time": _iso(time_unix_s),
        "time_unix_s": time_unix_s,
    }


class MqttPublisher:
    """Publish a gearbox's live estimates and alarm state to an MQTT broker (see the module docstring).

    Parameters
    ----------
    url : str
        ``mqtt://HOST[:PORT]/PREFIX``.
    gearbox_id : str
        The gearbox: the topics are ``PREFIX/GEARBOX/estimate`` and ``PREFIX/GEARBOX/state``.
    warn_arcmin, limit_arcmin : float, optional
        The gearbox's warning level and limit of the play, arcmin.
    connect_wait_s : float
        :meth:`start` waits this long for the first connection (estimates before it are dropped).
    tls : MqttTls, optional
        CA, client certificate and key for ``mqtts://`` (default: the system's CAs).
    figures : callable, optional
        ``figures()`` -> a dict added to the state message (the wear figures of the gearbox's
        history), called whenever the state changes.
    on_connection : callable, optional
        Called from paho's network thread as ``on_connection(True, "")`` on every connection and
        ``on_connection(False, reason)`` when the broker refuses one or a connection is lost (not at
        :meth:`close`): ``listen`` says so on stderr, and a test knows from it when estimates start to be dropped.

    Use as a context manager (or :meth:`start` / :meth:`close`); :meth:`publish` is called with
    every row. :meth:`counts` gives ``mqtt_published``, ``mqtt_dropped`` and ``mqtt_connections``.
    """

    def __init__(
        self,
        url: str,
        gearbox_id: str,
        warn_arcmin: float | None = None,
        limit_arcmin: float | None = None,
        connect_wait_s: float = 2.0,
        tls: MqttTls | None = None,
        figures: Callable[[], dict[str, Any]] | None = None,
        on_connection: Callable[[bool, str], None] | None = None,
    ) -> None:
        import paho.mqtt.client as mqtt  # loads only when publishing

        self.target = MqttTarget.parse(url)
        if not gearbox_id or any(c in gearbox_id for c in "/+#"):
            raise InvalidParameterError(f"--mqtt: the gearbox id {gearbox_id!r} must be non-empty without / + #")
        check_alarm_levels(warn_arcmin, limit_arcmin)
        self.gearbox_id = gearbox_id
        self.levels = (warn_arcmin, limit_arcmin)
        self.connect_wait_s = connect_wait_s
        self.published = 0
        self.dropped = 0
        self.connections = 0
        self._lock = threading.Lock()
        self._connected = threading.Event()
        self._closing = False
        self._on_connection = on_connection
        self._state: dict[str, Any] | None = None  # the newest state message
        self._figures_of = figures
        self._figures: dict[str, Any] = {}  # the wear figures as of the last change of state
        self._state_sent: str | None = None  # the state the broker has retained from us
        self._success = mqtt.MQTT_ERR_SUCCESS
        client = mqtt.Client(
            mqtt.CallbackAPIVersion.VERSION2, client_id=f"online-backlash-{gearbox_id}-{uuid.uuid4().hex[:8]}"
        )
        client.reconnect_delay_set(*RECONNECT_DELAY_S)
        client.max_queued_messages_set(MAX_QUEUED_MESSAGES)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        self._status_topic = self.target.topic(gearbox_id, "status")
        will = status_message(gearbox_id, "offline", "connection lost without a goodbye (last will)")
        client.will_set(self._status_topic, json.dumps(will), qos=1, retain=True)
        self._secure(client, tls)
        self._client = client

    def _secure(self, client: Any, tls: MqttTls | None) -> None:
        """TLS for ``mqtts://`` and the login for a user in the URL; files are checked up front."""
        import ssl

        if self.target.username is not None:
            client.username_pw_set(self.target.username, os.environ.get(PASSWORD_ENV))
        if tls is not None and not self.target.tls and any(vars(tls).values()):
            raise InvalidParameterError("--mqtt-ca/--mqtt-cert/--mqtt-key need an mqtts:// URL")
        if not self.target.tls:
            return
        tls = tls or MqttTls()
        for name, path in (("--mqtt-ca", tls.ca_file), ("--mqtt-cert", tls.cert_file), ("--mqtt-key", tls.key_file)):
            if path is not None and not os.path.isfile(path):
                raise InvalidParameterError(f"{path}: {name}: no such file")
        try:
            client.tls_set(ca_certs=tls.ca_file, certfile=tls.cert_file, keyfile=tls.key_file)
        except (ssl.SSLError, ValueError) as exc:
            raise InvalidParameterError(f"--mqtt: the TLS files were refused: {exc}") from exc

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> MqttPublisher:
        """Connect in the background (paho's network thread) and wait up to ``connect_wait_s`` for it."""
        self._client.connect_async(self.target.host, self.target.port, keepalive=30)
        self._client.loop_start()
        self._connected.wait(self.connect_wait_s)
        return self

    def close(self) -> None:
        """Say ``offline`` (retained; waited for up to ``connect_wait_s``), disconnect cleanly, stop the network
        thread."""
        self._closing = True
        if self._connected.is_set():
            message = status_message(self.gearbox_id, "offline", "stopped")
            info = self._client.publish(self._status_topic, json.dumps(message), qos=1, retain=True)
            if info.rc == self._success:
                try:
                    info.wait_for_publish(self.connect_wait_s)
                except (RuntimeError, ValueError):  # the connection went meanwhile: the last will says offline
                    pass
        self._client.disconnect()
        self._client.loop_stop()

    def __enter__(self) -> MqttPublisher:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def state(self) -> dict[str, Any] | None:
        """The newest state message (sent, retained, when the state changes and on every connection)."""
        with self._lock:
            return None if self._state is None else dict(self._state)

    @property
    def connected(self) -> bool:
        """Connected to the broker now."""
        return self._connected.is_set()

    def counts(self) -> dict[str, int]:
        """Estimates published and dropped (broker away), and connections made (1 + reconnections)."""
        return {"mqtt_published": self.published, "mqtt_dropped": self.dropped, "mqtt_connections": self.connections}

    # -- publishing -----------------------------------------------------------------------
    def publish(self, row: EstimateRow, time_unix_s: float) -> None:
        """Publish one estimate (calendar time ``time_unix_s``, UNIX seconds) and the state if it changed.

        Never blocks on the broker and never raises for it: while disconnected the estimate is
        counted in :attr:`dropped`.
        """
        status = live_state(row, time_unix_s, *self.levels)
        message = estimate_message(row, self.gearbox_id, status.state, time_unix_s)
        with self._lock:
            changed = self._state_sent != status.state
        if changed and self._figures_of is not None:
            self._figures = self._figures_of()
        with self._lock:
            self._state = {**state_message(status, self.gearbox_id, time_unix_s), **self._figures}
        if changed:
            self._send_state()
        sent = self._send(self.target.topic(self.gearbox_id, "estimate"), message, qos=0, retain=False)
        with self._lock:
            if sent:
                self.published += 1
            else:
                self.dropped += 1

    def _send(self, topic: str, message: dict[str, Any], qos: int, retain: bool) -> bool:
        """Hand one message to paho if connected (never under ``_lock``: paho calls back under its own)."""
        if not self._connected.is_set():
            return False
        info = self._client.publish(topic, json.dumps(message), qos=qos, retain=retain)
        return info.rc == self._success

    def _send_state(self) -> None:
        """Publish the newest state, retained; remember it if it went out."""
        with self._lock:
            state = self._state
        if state is not None and self._send(self.target.topic(self.gearbox_id, "state"), state, qos=1, retain=True):
            with self._lock:
                self._state_sent = state["state"]

    # -- paho callbacks (network thread) --------------------------------------------------
    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason_code: Any, properties: Any) -> None:
        if reason_code.is_failure:
            self._tell(False, f"refused: {reason_code}")
            return
        with self._lock:
            self.connections += 1
        self._connected.set()
        self._send(self._status_topic, status_message(self.gearbox_id, "online", "publishing"), qos=1, retain=True)
        self._send_state()  # retained again: a restarted broker may have lost it
        self._tell(True, "")

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason_code: Any, properties: Any) -> None:
        was_connected = self._connected.is_set()
        self._connected.clear()
        if was_connected and not self._closing:
            self._tell(False, f"lost: {reason_code}")

    def _tell(self, connected: bool, reason: str) -> None:
        if self._on_connection is not None:
            self._on_connection(connected, reason)


def unix_time_of(time_s: float, offset_s: float | None) -> tuple[float, float]:
    """``(time_unix_s, offset_s)`` of a live sample time: UNIX times stay, a device clock is placed
    so that its first estimate is now (as :class:`~online_backlash.tracking.GearboxTracker` places
    a live run). Pass the returned offset back with the next time."""
    if offset_s is None:
        offset_s = live_clock_offset(time_s)
    return time_s + offset_s, offset_s


__all__ = [
    "ARCMIN_PER_DEG",
    "MqttPublisher",
    "MqttTarget",
    "MqttTls",
    "estimate_message",
    "live_state",
    "state_message",
    "status_message",
    "unix_time_of",
]

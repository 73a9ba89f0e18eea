"""``--mqtt``: live estimates and the alarm state published to a real Mosquitto broker.

Each test starts its own broker (Debian's ``mosquitto``, :mod:`mqtt_server`) on a free localhost
port; a missing broker fails the tests (it does not skip them). The live source is a python-can
``virtual`` bus fed from a thread, as in ``test_cli_listen.py``; the broker is killed and
restarted in the middle of a run to show that the estimate and the raw capture go on and the
estimates meanwhile are dropped and counted.
"""

from __future__ import annotations

import csv
import gc
import json
import shutil
import socket
import subprocess
import sys
import threading
import warnings

import can
import mqtt_server
import paho.mqtt.client as mqtt
import pytest
from live_run import LIMIT_S, run_live, send_frames
from mqtt_server import BrokerCertificates, MosquittoBroker, MosquittoUnavailable
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.errors import InvalidParameterError
from online_backlash.log_fit import fit_recursive
from online_backlash.output_columns import REPORT_KEYS, EstimateRow
from online_backlash.publish import PASSWORD_ENV, MqttPublisher, MqttTarget, MqttTls, estimate_message, live_state
from online_backlash.replay import open_log
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames

T0 = 1.75e9  # the frames' clock: UNIX seconds
CAN_OPTIONS = ["--interface", "virtual", *RIG_CAN]
#: The line ``listen --mqtt`` writes on stderr when the publisher has connected.
CONNECTED = r"mqtt: 127\.0\.0\.1:\d+: connected$"
MESSAGE_KEYS = set(REPORT_KEYS) | {"backlash_std_deg", "n_reversals", "time", "time_unix_s", "gearbox", "state"}


@pytest.fixture
def mqtt_broker(tmp_path):
    """A Mosquitto broker of this test's own on 127.0.0.1 (stopped afterwards); the test may stop and restart it."""
    broker = MosquittoBroker(tmp_path / "mosquitto")
    try:
        broker.start()
    except MosquittoUnavailable as exc:
        pytest.fail(str(exc), pytrace=False)
    yield broker
    broker.stop()
    shutil.rmtree(broker.folder, ignore_errors=True)


def test_a_missing_broker_is_named_and_leaves_no_file_open(tmp_path, monkeypatch):
    """Without Debian's mosquitto the broker fails naming the package, and opens no log it would leave unclosed."""
    monkeypatch.setattr(mqtt_server.shutil, "which", lambda *_, **__: None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(MosquittoUnavailable, match="install Debian's 'mosquitto' package"):
            MosquittoBroker(tmp_path).start()
        gc.collect()  # an unclosed file warns when it is collected
    assert [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)] == []


class Subscriber:
    """Every message under ``PREFIX/#``, as ``(topic, payload dict, retained)``; reconnects and resubscribes by itself.
    Made once the broker has acknowledged the subscription: nothing published afterwards is missed."""

    def __init__(self, broker: MosquittoBroker, prefix: str, login: tuple[str, str] | None = None) -> None:
        self.messages: list[tuple[str, dict, bool]] = []
        self._changed = threading.Condition()
        subscribed = threading.Event()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        if broker.tls is not None:
            self.client.tls_set(ca_certs=str(broker.tls.ca))
        if login is not None:
            self.client.username_pw_set(*login)
        self.client.reconnect_delay_set(1, 1)
        self.client.on_connect = lambda client, *_: client.subscribe(f"{prefix}/#", qos=1)
        self.client.on_subscribe = lambda *_: subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", broker.port)
        self.client.loop_start()
        assert subscribed.wait(LIMIT_S), "the broker never acknowledged the subscription"

    def _on_message(self, _client, _userdata, msg) -> None:
        with self._changed:
            self.messages.append((msg.topic, json.loads(msg.payload), bool(msg.retain)))
            self._changed.notify_all()

    def on(self, topic: str) -> list[dict]:
        with self._changed:
            return [payload for t, payload, _ in self.messages if t == topic]

    def wait(self, condition, what: str) -> None:
        """Wait until ``condition()`` holds, looked at on every message that arrives."""
        with self._changed:
            assert self._changed.wait_for(condition, LIMIT_S), f"never happened within {LIMIT_S} s: {what}"

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def rig_frames(duration_s: float) -> list[can.Message]:
    rec = simulate_rig(duration_s=duration_s, play_deg=0.3, reversal_s=(0.4, 0.8), seed=12)  # 18 arcmin of play
    return list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), T0))


def due_estimates(frames: list[can.Message], path, every_s: float) -> list[EstimateRow]:
    """The estimates a run on ``frames`` makes: the frames in a BLF written by python-can, replayed (live = replay)."""
    with can.Logger(str(path)) as writer:
        for frame in frames:
            writer.on_message_received(frame)
    rows: list[EstimateRow] = []
    log = open_log(path, dbc=RIG_DBC, motor_signal="MotorAngle.Count", load_signal="LoadAngle.Count")
    listen_defaults = {"memory_reversals": 10.0, "sample_period_s": 0.001}
    fit_recursive(log.iter_chunks(), 30.0, every_s=every_s, trace=rows.append, **listen_defaults)
    return rows


@pytest.mark.slow
def test_listen_publishes_reconnects_after_a_broker_crash_and_counts_the_dropped(mqtt_broker, tmp_path, capsys):
    frames = rig_frames(18.0)  # estimates from 10 s of data (the warm start), then one every 0.1 s
    # the broker is away while the data from 12.05 s to 15.05 s are learned: cut between two estimates
    cuts = [next(i for i, f in enumerate(frames) if f.timestamp >= T0 + t) for t in (12.05, 15.05)]
    thirds = [frames[: cuts[0]], frames[cuts[0] : cuts[1]], frames[cuts[1] :]]
    due = due_estimates(frames, tmp_path / "frames.blf", 0.1)
    # the samples learned at the last estimate of the first part, and of the second
    last_of = [max(r.n_samples for r in due if r.time_s < frames[cut].timestamp) for cut in cuts]
    first_part = [r.n_samples for r in due if r.n_samples <= last_of[0]]  # the estimates due before the crash
    channel, prefix = "mqtt-listen", "plant/hall-3"
    estimate_topic, state_topic = f"{prefix}/GB-7/estimate", f"{prefix}/GB-7/state"
    sub = Subscriber(mqtt_broker, prefix)
    seen = {}

    def scenario(stderr):
        stderr.wait_for(CONNECTED)  # else the first estimates could be due before the publisher is connected
        send_frames(channel, thirds[0])
        sub.wait(lambda: [m["samples"] for m in sub.on(estimate_topic)] == first_part, "the first part's estimates")
        seen["before"] = len(sub.on(estimate_topic))
        mqtt_broker.stop()  # the broker crashes mid-run
        stderr.wait_for(r"mqtt: 127\.0\.0\.1:\d+: connection lost")  # the publisher knows: from now on it drops
        send_frames(channel, thirds[1])  # estimated while the broker is away
        stderr.wait_for(rf"arcmin +{last_of[1]} samples,")  # the status line of the second part's last estimate
        states_before = len(sub.on(state_topic))
        mqtt_broker.start()
        # the publisher sends its state again on reconnection: once it arrives, both are connected
        sub.wait(lambda: len(sub.on(state_topic)) > states_before, "the state was published again after the restart")
        seen["restarted"] = len(sub.on(estimate_topic))
        send_frames(channel, thirds[2])  # then Ctrl-C: the frames still waiting on the bus are learned too

    argv = [
        "listen",
        "can",
        "--channel",
        channel,
        *CAN_OPTIONS[2:],
        "--interface",
        "virtual",
        "--ratio",
        30,
        "--raw-log",
        tmp_path / "raw",
        "--json",
        "--mqtt",
        mqtt_broker.url(prefix),
        "--gearbox",
        "GB-7",
        "--every",
        0.1,
        "--warn-arcmin",
        10,
        "--limit-arcmin",
        15,
    ]
    try:
        code = run_live(argv, scenario)
        assert code == 0
        live = json.loads(capsys.readouterr().out)
        sub.wait(lambda: len(sub.on(estimate_topic)) >= live["mqtt_published"], "every estimate published arrived")
    finally:
        sub.close()
    estimates = sub.on(estimate_topic)

    # the estimate and the raw capture went on: every frame arrived, and the raw log replays to the same estimate
    assert live["frames"] == len(frames) and live["corrupt"] == 0 and live["samples"] > 5000
    trace = tmp_path / "trace.csv"
    argv = [
        "estimate",
        str(tmp_path / "raw"),
        *CAN_OPTIONS[2:],
        "--ratio",
        "30",
        "--json",
        "--trace",
        str(trace),
        "--every",
        "0.1",
    ]
    assert main(argv) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert replayed["backlash_deg"] == live["backlash_deg"] and replayed["samples"] == live["samples"]
    with trace.open() as f:
        replayed_times = [float(r["time"]) for r in csv.DictReader(f)]
    assert replayed_times == pytest.approx([r.time_s for r in due], abs=1e-6)  # the estimates of the run, replayed

    # what was due while the broker was away was dropped and counted; publishing resumed after the restart
    away = [last_of[0] < r.n_samples <= last_of[1] for r in due]  # due while the broker was away
    assert live["mqtt_dropped"] == sum(away) > 0 and live["mqtt_connections"] == 2
    assert seen["restarted"] == seen["before"] == len(first_part)  # nothing was queued for later
    assert len(estimates) == live["mqtt_published"] and live["mqtt_published"] + live["mqtt_dropped"] == len(due)
    # what arrived is what was due, less the block of estimates due while the broker was away
    arrived = [r for r, dropped in zip(due, away) if not dropped]
    assert [m["samples"] for m in estimates] == [r.n_samples for r in arrived]
    assert [m["time_unix_s"] for m in estimates] == pytest.approx([r.time_s for r in arrived], abs=1e-6)

    # topics and keys; the last message is the summary's estimate; the play (18 arcmin) is over the limit
    assert all(set(m) == MESSAGE_KEYS and m["gearbox"] == "GB-7" for m in estimates)
    assert estimates[-1]["backlash_deg"] == live["backlash_deg"] and estimates[-1]["state"] == "alarm"
    assert estimates[-1]["time_unix_s"] == pytest.approx(frames[-1].timestamp, abs=0.01)
    assert estimates[-1]["time"].startswith("2025-06-15T")  # ISO 8601, UTC, of the frames' clock

    # the state, retained: a subscriber that comes later gets it at once, flagged as retained
    late = Subscriber(mqtt_broker, prefix)
    try:
        late.wait(lambda: len(late.messages) >= 2, "the retained state and status")
    finally:
        late.close()
    retained = {topic: payload for topic, payload, flag in late.messages if flag}
    assert len(late.messages) == len(retained) == 2  # the state, and the publisher's status
    assert retained[state_topic]["state"] == "alarm" and retained[state_topic]["limit_arcmin"] == 15
    assert retained[f"{prefix}/GB-7/status"]["status"] == "offline"  # the listener stopped, and said so


def test_track_listen_publishes_with_the_stored_levels(mqtt_broker, tmp_path, capsys):
    frames = rig_frames(14.0)  # estimates at 10, 11, 12, 13 s of data
    channel, prefix = "mqtt-track", "fleet"
    sub = Subscriber(mqtt_broker, prefix)
    db = tmp_path / "w.db"
    assert (
        main(
            [
                "track",
                "--listen",
                "can",
                "--channel",
                channel,
                *CAN_OPTIONS,
                "--raw-log",
                str(tmp_path / "raw0"),
                "--ratio",
                "30",
                "--db",
                str(db),
                "--gearbox",
                "g1",
                "--warn-arcmin",
                "15",
                "--limit-arcmin",
                "25",
                "--duration",
                "0.2",
                "--timeout",
                "0.1",
            ]
        )
        != 0
    )  # nothing arrives: an error, but the levels are stored with the gearbox
    capsys.readouterr()
    argv = [
        "track",
        "--listen",
        "can",
        "--channel",
        channel,
        *CAN_OPTIONS,
        "--raw-log",
        tmp_path / "raw",
        "--ratio",
        30,
        "--db",
        db,
        "--gearbox",
        "g1",
        "--every",
        1,
        "--mqtt",
        mqtt_broker.url(prefix),
        "--json",
    ]

    def scenario(stderr):
        stderr.wait_for(CONNECTED)
        send_frames(channel, frames)  # then Ctrl-C: the frames still waiting on the bus are learned too

    try:
        code = run_live(argv, scenario)
        assert code == 0
        result = json.loads(capsys.readouterr().out)
        published = result["counters"]["mqtt_published"]
        sub.wait(lambda: len(sub.on("fleet/g1/estimate")) >= published, "every estimate published arrived")
    finally:
        sub.close()
    estimates = sub.on("fleet/g1/estimate")
    assert result["estimates_added"] == len(estimates) == 4 and result["counters"]["mqtt_dropped"] == 0
    assert all(set(m) == MESSAGE_KEYS for m in estimates)
    assert estimates[-1]["backlash_deg"] == result["last_estimate"]["backlash_deg"]
    assert estimates[-1]["time_unix_s"] == result["last_estimate"]["time_unix_s"]
    assert estimates[-1]["state"] == "warning"  # 18 arcmin: over the stored warning level 15, under the limit 25
    assert sub.on("fleet/g1/state")[-1]["state"] == "warning"


def test_mqtt_needs_a_gearbox_and_a_well_formed_url(tmp_path, capsys):
    base = ["listen", "serial", "--port", "loop://", "--format", "ascii", "--ratio", "30", "--raw-log", str(tmp_path)]
    base += ["--duration", "0.1"]
    assert main([*base, "--mqtt", "mqtt://127.0.0.1:1883/p"]) == 1
    assert "give --gearbox ID" in capsys.readouterr().err
    assert main([*base, "--mqtt", "http://127.0.0.1/p", "--gearbox", "g"]) == 1
    assert "expected mqtt://HOST:PORT/PREFIX (or mqtts:// for TLS), got 'http://127.0.0.1/p'" in capsys.readouterr().err
    assert (
        main(
            [
                "track",
                "log.csv",
                "--ratio",
                "30",
                "--db",
                str(tmp_path / "w.db"),
                "--gearbox",
                "g",
                "--mqtt",
                "mqtt://h/p",
            ]
        )
        == 1
    )
    assert "use it with --listen" in capsys.readouterr().err


@pytest.mark.parametrize(
    "url",
    [
        "mqtt://host",
        "mqtt://host:0/p",
        "mqtt://:1883/p",
        "mqtx://host/p",
        "mqtt://u:secret@host/p",
        "mqtt://host/a/#",
        "mqtt://host:x/p",
        "mqtt://h/p?q=1",
    ],
)
def test_bad_urls_are_refused(url):
    with pytest.raises(InvalidParameterError, match="--mqtt"):
        MqttTarget.parse(url)


def test_a_good_url_and_the_topics():
    target = MqttTarget.parse("mqtt://broker.plant:1884/backlash/hall-3/")
    assert (target.host, target.port, target.prefix) == ("broker.plant", 1884, "backlash/hall-3")
    assert target.topic("GB-7", "estimate") == "backlash/hall-3/GB-7/estimate"
    assert MqttTarget.parse("mqtt://localhost/p").port == 1883
    secure = MqttTarget.parse("mqtts://rig@localhost/p")
    assert (secure.port, secure.tls, secure.username) == (8883, True, "rig")


def row(play_deg: float, std_deg: float) -> EstimateRow:
    return EstimateRow(12.5, 4000, play_deg, std_deg, 0.1, play_deg - 0.1, 1.0, 1.0, 1e-3, 7)


@pytest.mark.parametrize(
    ("play_deg", "std_deg", "warn", "limit", "state"),
    [
        (0.30, 0.001, 15.0, 25.0, "warning"),
        (0.30, 0.001, 20.0, 25.0, "ok"),
        (0.30, 0.001, None, 15.0, "alarm"),
        (0.30, 0.001, 15.0, None, "unknown"),  # no limit
        (0.30, float("nan"), 15.0, 25.0, "unknown"),  # not observable
    ],
)
def test_the_state_of_a_live_estimate(play_deg, std_deg, warn, limit, state):
    assert live_state(row(play_deg, std_deg), T0, warn, limit).state == state


def test_the_message_has_the_estimate_keys_and_no_nan():
    message = estimate_message(row(0.3, float("nan")), "GB-7", "unknown", T0)
    assert set(message) == MESSAGE_KEYS and list(message)[: len(REPORT_KEYS)] == list(REPORT_KEYS)
    assert (
        message["backlash_arcmin"] == pytest.approx(18.0)
        and message["samples"] == 4000
        and message["method"] == "recursive"
    )
    assert message["backlash_std_deg"] is None and json.loads(json.dumps(message)) == message
    assert message["time"] == "2025-06-15T15:06:40+00:00"


def test_a_publisher_without_a_broker_drops_and_counts():
    with socket.socket() as held:  # a port of this test's where nobody listens: every connection is refused
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        with MqttPublisher(f"mqtt://127.0.0.1:{port}/p", "g", limit_arcmin=20.0, connect_wait_s=0.2) as publisher:
            for _ in range(3):
                publisher.publish(row(0.3, 0.001), T0)
            assert not publisher.connected
    assert publisher.counts() == {"mqtt_published": 0, "mqtt_dropped": 3, "mqtt_connections": 0}


def test_status_is_online_while_publishing_offline_after_and_the_last_will_covers_a_crash(mqtt_broker, tmp_path):
    sub = Subscriber(mqtt_broker, "p")
    status = "p/GB-1/status"
    try:
        with MqttPublisher(mqtt_broker.url("p"), "GB-1", connect_wait_s=LIMIT_S) as publisher:
            assert publisher.connected
            sub.wait(lambda: len(sub.on(status)) == 1, "the status online")
            assert sub.on(status)[0]["status"] == "online"
        sub.wait(lambda: len(sub.on(status)) == 2, "the status offline")
        assert sub.on(status)[-1]["status"] == "offline" and sub.on(status)[-1]["reason"] == "stopped"
        # a publisher process that dies without a goodbye: the broker publishes its last will
        script = (
            "import sys, time; from online_backlash.publish import MqttPublisher\n"
            f"p = MqttPublisher({mqtt_broker.url('p')!r}, 'GB-2', connect_wait_s={LIMIT_S}).start()\n"
            "print(p.connected, flush=True); sys.stdin.read()\n"  # connected, until killed
        )
        pipes = {"stdin": subprocess.PIPE, "stdout": subprocess.PIPE, "text": True}
        with subprocess.Popen([sys.executable, "-c", script], **pipes) as child:
            try:
                assert child.stdout is not None and child.stdout.readline().strip() == "True"
                sub.wait(lambda: len(sub.on("p/GB-2/status")) == 1, "the second publisher's status online")
                assert sub.on("p/GB-2/status")[0]["status"] == "online"
            finally:
                child.kill()
        sub.wait(lambda: len(sub.on("p/GB-2/status")) == 2, "the last will")
        will = sub.on("p/GB-2/status")[-1]
        assert will["status"] == "offline" and "last will" in will["reason"]
    finally:
        sub.close()


# paho-mqtt 2.2 leaves the socket of a refused TLS handshake for the garbage collector (its reconnect loop)
@pytest.mark.filterwarnings("ignore:unclosed <ssl.SSLSocket:ResourceWarning")
@pytest.mark.filterwarnings("ignore:Exception ignored in. <ssl.SSLSocket:pytest.PytestUnraisableExceptionWarning")
def test_tls_with_a_private_ca_and_a_login(tmp_path, monkeypatch):
    certs = BrokerCertificates.make(tmp_path / "certs")
    broker = MosquittoBroker(tmp_path / "broker", tls=certs, users={"rig": "s3cret"})
    try:
        broker.start()
    except MosquittoUnavailable as exc:
        pytest.fail(str(exc), pytrace=False)
    try:
        sub = Subscriber(broker, "plant", login=("rig", "s3cret"))
        try:
            monkeypatch.setenv(PASSWORD_ENV, "s3cret")
            tls = MqttTls(str(certs.ca))
            url = broker.url("plant", "rig")
            with MqttPublisher(url, "GB-3", limit_arcmin=20.0, tls=tls, connect_wait_s=LIMIT_S) as pub:
                assert pub.connected
                pub.publish(row(0.3, 0.001), T0)
                sub.wait(lambda: sub.on("plant/GB-3/estimate"), "the estimate over TLS")
            assert sub.on("plant/GB-3/estimate")[0]["backlash_arcmin"] == pytest.approx(18.0)
        finally:
            sub.close()
        # the system's CAs do not know the test CA; a wrong password is refused: never connected, estimates dropped
        for tls, password in ((None, "s3cret"), (MqttTls(str(certs.ca)), "wrong")):
            monkeypatch.setenv(PASSWORD_ENV, password)
            with MqttPublisher(broker.url("plant", "rig"), "GB-3", tls=tls, connect_wait_s=1.0) as pub:
                pub.publish(row(0.3, 0.001), T0)
                assert not pub.connected
            assert pub.counts() == {"mqtt_published": 0, "mqtt_dropped": 1, "mqtt_connections": 0}
    finally:
        broker.stop()


def test_tls_files_are_checked_up_front(tmp_path):
    with pytest.raises(InvalidParameterError, match="need an mqtts:// URL"):
        MqttPublisher("mqtt://127.0.0.1/p", "g", tls=MqttTls(ca_file=str(tmp_path / "ca.pem")))
    with pytest.raises(InvalidParameterError, match=r"ca\.pem: --mqtt-ca: no such file"):
        MqttPublisher("mqtts://127.0.0.1/p", "g", tls=MqttTls(ca_file=str(tmp_path / "ca.pem")))

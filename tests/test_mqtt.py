"""``--mqtt``: live estimates and the alarm state published to a real Mosquitto broker.

Each test starts its own broker (Debian's ``mosquitto``, :mod:`mqtt_server`) on a free localhost
port; a missing broker fails the tests (it does not skip them). The live source is a python-can
``virtual`` bus fed from a thread, as in ``test_cli_listen.py``; the broker is killed and
restarted in the middle of a run to show that the estimate and the raw capture go on and the
estimates meanwhile are dropped and counted.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time

import can
import paho.mqtt.client as mqtt
import pytest
from can.interfaces.virtual import channels
from mqtt_server import BrokerCertificates, MosquittoBroker, MosquittoUnavailable

from online_backlash.cli import main
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.errors import InvalidParameterError
from online_backlash.publish import PASSWORD_ENV, MqttPublisher, MqttTarget, MqttTls, estimate_message, live_state
from online_backlash.rig import simulate_rig
from online_backlash.rig_logs import rig_can_frames
from online_backlash.rows import REPORT_KEYS, EstimateRow

T0 = 1.75e9  # the frames' clock: UNIX seconds
CAN_OPTIONS = ["--interface", "virtual", "--dbc", "rig", "--motor-signal", "MotorAngle.Count", "--load-signal", "LoadAngle.Count"]
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


class Subscriber:
    """Every message under ``PREFIX/#``, as ``(topic, payload dict, retained)``; reconnects and resubscribes by itself."""

    def __init__(self, broker: MosquittoBroker, prefix: str, login: tuple[str, str] | None = None) -> None:
        self.messages: list[tuple[str, dict, bool]] = []
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        if broker.tls is not None:
            self.client.tls_set(ca_certs=str(broker.tls.ca))
        if login is not None:
            self.client.username_pw_set(*login)
        self.client.reconnect_delay_set(1, 1)
        self.client.on_connect = lambda client, *_: client.subscribe(f"{prefix}/#", qos=1)
        self.client.on_message = lambda _c, _u, msg: self.messages.append((msg.topic, json.loads(msg.payload), bool(msg.retain)))
        self.client.connect("127.0.0.1", broker.port)
        self.client.loop_start()

    def on(self, topic: str) -> list[dict]:
        return [payload for t, payload, _ in list(self.messages) if t == topic]

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def wait_for(condition, limit_s: float = 30.0) -> bool:
    deadline = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def rig_frames(duration_s: float) -> list[can.Message]:
    rec = simulate_rig(duration_s=duration_s, play_deg=0.3, reversal_s=(0.4, 0.8), seed=12)  # 18 arcmin of play
    return list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), T0))


def feed(channel: str, frames: list[can.Message]) -> None:
    """Send ``frames`` on a virtual bus and wait until the listener has taken them all."""
    tx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    try:
        for frame in frames:
            tx.send(frame)
        assert wait_for(lambda: all(q.empty() for q in channels.get(channel, [])))
    finally:
        tx.shutdown()
    time.sleep(0.3)  # the pipeline learns what it took


def run_live(argv: list, channel: str, scenario) -> int:
    """Run the CLI with a live CAN source while ``scenario()`` feeds it from a thread, then Ctrl-C; its exit code."""
    failure: list[BaseException] = []

    def drive():
        try:
            assert wait_for(lambda: len(channels.get(channel, [])) >= 1)  # the listener's bus is open
            scenario()
        except BaseException as exc:  # reported after the run
            failure.append(exc)
        finally:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C ends the live run with its summary

    driver = threading.Thread(target=drive)
    driver.start()
    try:
        code = main([str(a) for a in argv])
    finally:
        driver.join()
    if failure:
        raise failure[0]
    return code


@pytest.mark.slow
def test_listen_publishes_reconnects_after_a_broker_crash_and_counts_the_dropped(mqtt_broker, tmp_path, capsys):
    frames = rig_frames(18.0)  # estimates from 10 s of data (the warm start), then one every 0.1 s
    cuts = [next(i for i, f in enumerate(frames) if f.timestamp >= T0 + t) for t in (12.0, 15.0)]  # the broker is away 12-15 s
    thirds = [frames[: cuts[0]], frames[cuts[0] : cuts[1]], frames[cuts[1] :]]
    channel, prefix = "mqtt-listen", "plant/hall-3"
    estimate_topic, state_topic = f"{prefix}/GB-7/estimate", f"{prefix}/GB-7/state"
    sub = Subscriber(mqtt_broker, prefix)
    seen = {}

    def scenario():
        feed(channel, thirds[0])
        assert wait_for(lambda: len(sub.on(estimate_topic)) >= 5), "no estimates before the crash"
        mqtt_broker.stop()  # the broker crashes mid-run
        time.sleep(0.5)
        seen["before"] = len(sub.on(estimate_topic))
        feed(channel, thirds[1])  # estimated while the broker is away
        states_before = len(sub.on(state_topic))
        mqtt_broker.start()
        # the publisher sends its state again on reconnection: once it arrives, both are connected
        assert wait_for(lambda: len(sub.on(state_topic)) > states_before), "the state was not published again after the restart"
        seen["restarted"] = len(sub.on(estimate_topic))
        feed(channel, thirds[2])

    argv = ["listen", "can", "--channel", channel, *CAN_OPTIONS[2:], "--interface", "virtual", "--ratio", 30,
            "--raw-log", tmp_path / "raw", "--json", "--mqtt", mqtt_broker.url(prefix), "--gearbox", "GB-7",
            "--every", 0.1, "--warn-arcmin", 10, "--limit-arcmin", 15]
    try:
        code = run_live(argv, channel, scenario)
        time.sleep(0.3)
    finally:
        sub.close()
    assert code == 0
    live = json.loads(capsys.readouterr().out)
    estimates = sub.on(estimate_topic)

    # the estimate and the raw capture went on: every frame arrived, and the raw log replays to the same estimate
    assert live["frames"] == len(frames) and live["corrupt"] == 0 and live["samples"] > 5000
    trace = tmp_path / "trace.csv"
    argv = ["estimate", str(tmp_path / "raw"), *CAN_OPTIONS[2:], "--ratio", "30", "--json", "--trace", str(trace), "--every", "0.1"]
    assert main(argv) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert replayed["backlash_deg"] == live["backlash_deg"] and replayed["samples"] == live["samples"]
    with trace.open() as f:
        due = [float(r["time"]) for r in csv.DictReader(f)]  # the estimates of the run, replayed

    # what was due while the broker was away was dropped and counted; publishing resumed after the restart
    assert live["mqtt_dropped"] > 0 and live["mqtt_connections"] == 2
    assert seen["restarted"] == seen["before"]  # nothing was queued for later
    assert len(estimates) > seen["restarted"] and live["mqtt_published"] == len(estimates)
    assert live["mqtt_published"] + live["mqtt_dropped"] == len(due)
    # what arrived is what was due, less one block of consecutive estimates: those due while the broker was away
    times = [m["time_unix_s"] for m in estimates]
    cut = next(i for i, (t, d) in enumerate(zip(times, due)) if abs(t - d) > 1e-6)
    assert times == pytest.approx(due[:cut] + due[cut + live["mqtt_dropped"] :], abs=1e-6)

    # topics and keys; the last message is the summary's estimate; the play (18 arcmin) is over the limit
    assert all(set(m) == MESSAGE_KEYS and m["gearbox"] == "GB-7" for m in estimates)
    assert estimates[-1]["backlash_deg"] == live["backlash_deg"] and estimates[-1]["state"] == "alarm"
    assert estimates[-1]["time_unix_s"] == pytest.approx(frames[-1].timestamp, abs=0.01)
    assert estimates[-1]["time"].startswith("2025-06-15T")  # ISO 8601, UTC, of the frames' clock
    assert [m["samples"] for m in estimates] == sorted(m["samples"] for m in estimates)

    # the state, retained: a subscriber that comes later gets it at once, flagged as retained
    late = Subscriber(mqtt_broker, prefix)
    try:
        assert wait_for(lambda: late.messages, 10.0)
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
    assert main(["track", "--listen", "can", "--channel", channel, *CAN_OPTIONS, "--raw-log", str(tmp_path / "raw0"), "--ratio", "30",
                 "--db", str(db), "--gearbox", "g1", "--warn-arcmin", "15", "--limit-arcmin", "25", "--duration", "0.2",
                 "--timeout", "0.1"]) != 0  # nothing arrives: an error, but the levels are stored with the gearbox
    capsys.readouterr()
    argv = ["track", "--listen", "can", "--channel", channel, *CAN_OPTIONS, "--raw-log", tmp_path / "raw", "--ratio", 30,
            "--db", db, "--gearbox", "g1", "--every", 1, "--mqtt", mqtt_broker.url(prefix), "--json"]
    try:
        code = run_live(argv, channel, lambda: feed(channel, frames))
        assert wait_for(lambda: len(sub.on("fleet/g1/estimate")) >= 4, 5.0)
    finally:
        sub.close()
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    estimates = sub.on("fleet/g1/estimate")
    assert result["estimates_added"] == len(estimates) == 4 and result["counters"]["mqtt_dropped"] == 0
    assert all(set(m) == MESSAGE_KEYS for m in estimates)
    assert estimates[-1]["backlash_deg"] == result["last_estimate"]["backlash_deg"]
    assert estimates[-1]["time_unix_s"] == result["last_estimate"]["time_unix_s"]
    assert estimates[-1]["state"] == "warning"  # 18 arcmin: over the stored warning level 15, under the limit 25
    assert sub.on("fleet/g1/state")[-1]["state"] == "warning"


def test_mqtt_needs_a_gearbox_and_a_well_formed_url(tmp_path, capsys):
    base = ["listen", "serial", "--port", "loop://", "--format", "ascii", "--ratio", "30", "--raw-log", str(tmp_path), "--duration", "0.1"]
    assert main([*base, "--mqtt", "mqtt://127.0.0.1:1883/p"]) == 1
    assert "give --gearbox ID" in capsys.readouterr().err
    assert main([*base, "--mqtt", "http://127.0.0.1/p", "--gearbox", "g"]) == 1
    assert "expected mqtt://HOST:PORT/PREFIX (or mqtts:// for TLS), got 'http://127.0.0.1/p'" in capsys.readouterr().err
    assert main(["track", "log.csv", "--ratio", "30", "--db", str(tmp_path / "w.db"), "--gearbox", "g", "--mqtt", "mqtt://h/p"]) == 1
    assert "use it with --listen" in capsys.readouterr().err


@pytest.mark.parametrize(
    "url", ["mqtt://host", "mqtt://host:0/p", "mqtt://:1883/p", "mqtx://host/p", "mqtt://u:secret@host/p", "mqtt://host/a/#", "mqtt://host:x/p", "mqtt://h/p?q=1"]
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
    assert message["backlash_arcmin"] == pytest.approx(18.0) and message["samples"] == 4000 and message["method"] == "recursive"
    assert message["backlash_std_deg"] is None and json.loads(json.dumps(message)) == message
    assert message["time"] == "2025-06-15T15:06:40+00:00"


def test_a_publisher_without_a_broker_drops_and_counts(tmp_path):
    port = MosquittoBroker(tmp_path).port  # a free port where nobody listens
    with MqttPublisher(f"mqtt://127.0.0.1:{port}/p", "g", limit_arcmin=20.0, connect_wait_s=0.2) as publisher:
        for _ in range(3):
            publisher.publish(row(0.3, 0.001), T0)
        assert not publisher.connected
    assert publisher.counts() == {"mqtt_published": 0, "mqtt_dropped": 3, "mqtt_connections": 0}


def test_status_is_online_while_publishing_offline_after_and_the_last_will_covers_a_crash(mqtt_broker, tmp_path):
    sub = Subscriber(mqtt_broker, "p")
    status = "p/GB-1/status"
    try:
        with MqttPublisher(mqtt_broker.url("p"), "GB-1", connect_wait_s=5.0) as publisher:
            assert publisher.connected
            assert wait_for(lambda: [m["status"] for m in sub.on(status)] == ["online"])
        assert wait_for(lambda: len(sub.on(status)) == 2)
        assert sub.on(status)[-1]["status"] == "offline" and sub.on(status)[-1]["reason"] == "stopped"
        # a publisher process that dies without a goodbye: the broker publishes its last will
        script = (
            "import sys, time; from online_backlash.publish import MqttPublisher\n"
            f"p = MqttPublisher({mqtt_broker.url('p')!r}, 'GB-2', connect_wait_s=5.0).start()\n"
            "print(p.connected, flush=True); time.sleep(60)\n"
        )
        with subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True) as child:
            try:
                assert child.stdout is not None and child.stdout.readline().strip() == "True"
                assert wait_for(lambda: [m["status"] for m in sub.on("p/GB-2/status")] == ["online"])
            finally:
                child.kill()
        assert wait_for(lambda: len(sub.on("p/GB-2/status")) == 2)
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
            with MqttPublisher(broker.url("plant", "rig"), "GB-3", limit_arcmin=20.0, tls=MqttTls(str(certs.ca)), connect_wait_s=10.0) as pub:
                assert pub.connected
                pub.publish(row(0.3, 0.001), T0)
                assert wait_for(lambda: sub.on("plant/GB-3/estimate"))
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

"""``online-backlash opcua``: the fleet over OPC UA, checked with asyncua's client on localhost.

The server runs as a process (``online-backlash opcua``) over a store that ``track`` fills with the
bundled wear series; the client browses, reads, subscribes, and is refused where it should be.
Every wait is on a line the server prints or a notification the client receives, never a sleep.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import select
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID

from online_backlash.opcua.units import unit_id

WEAR = Path(__file__).resolve().parents[1] / "src" / "online_backlash" / "data" / "wear"
SERIES = json.loads((WEAR / "series.json").read_text())  # 60 daily snapshots, play 12 -> 18 arcmin
TRACK = ("--ratio", "30", "--gearbox", "GB-7", "--every", "30", "--units", "counts", "--hours-column", "hours")
COUNTS = ("--motor-cpr", "16384", "--load-cpr", "131072", "--quiet")
USER, PASSWORD = "plant", "s3cret-pass"
CLIENT_URI = "urn:online-backlash:test-client"
CLI = "import sys; from online_backlash.cli import main; sys.exit(main())"
WAIT_S = 120.0  # the longest any one notification may take (a track run compiles its kernels first)


def _track(db: Path, *days: int, levels: tuple[str, ...] = ()) -> None:
    logs = [str(WEAR / SERIES["logs"][d]["file"]) for d in days]
    subprocess.run(
        [sys.executable, "-c", CLI, "track", *logs, "--db", str(db), *TRACK, *COUNTS, *levels], check=True, timeout=600
    )


def _history(db: Path) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", CLI, "history", "--db", str(db), "--gearbox", "GB-7", "--json", "--max-age-h", "1e6"],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    return json.loads(done.stdout)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _client_certificate(folder: Path, keys: Path, name: str) -> tuple[Path, Path]:
    """A client application certificate made as OPC UA clients make theirs (asyncua's helper), its key in ``keys``."""
    cert, key = folder / f"{name}.der", keys / f"{name}.pem"
    asyncio.run(
        setup_self_signed_certificate(
            key, cert, CLIENT_URI, "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": name}
        )
    )
    return cert, key


@contextlib.contextmanager
def _serving(folder: Path, *argv: str):
    """``online-backlash opcua ARGV`` on a free localhost port, as a process; yields its endpoint and start line."""
    url = f"opc.tcp://127.0.0.1:{_free_port()}/online-backlash"
    log = folder / f"opcua-{len(list(folder.glob('opcua-*.log')))}.log"
    with open(log, "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-c", CLI, "opcua", "--endpoint", url, *argv],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            env={**os.environ, "ONLINE_BACKLASH_OPCUA_PASSWORD": PASSWORD},
        )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], WAIT_S)
        line = proc.stdout.readline() if ready else ""
        assert f"over OPC UA on {url}" in line, f"opcua did not start: {line!r} {log.read_text()}"
        yield url, line
    finally:
        proc.terminate()
        code = proc.wait(timeout=30)
        proc.stdout.close()
        assert code == 0, log.read_text()


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    """A store with the first seven snapshots of GB-7 (12-12.6 arcmin; warning 13, limit 21 arcmin: ok), a trusted and
    an untrusted client certificate, and ``online-backlash opcua`` serving the store; yields a dict of what the tests
    need."""
    d = tmp_path_factory.mktemp("opcua")
    db = d / "wear.db"
    _track(db, *range(7), levels=("--warn-arcmin", "13", "--limit-arcmin", "21"))
    trusted, keys = d / "trusted", d / "keys"
    trusted.mkdir()
    keys.mkdir()
    cert, key = _client_certificate(trusted, keys, "control-room")
    other = _client_certificate(keys, keys, "unknown-laptop")
    argv = ("--db", str(db), "--pki", str(d / "pki"), "--trust", str(trusted), "--user", USER)
    with _serving(d, *argv, "--poll", "0.5", "--max-age-h", "1e6") as (url, line):
        assert "certificate made in" in line and (d / "pki" / "server-cert.der").is_file()
        yield {"db": db, "url": url, "cert": cert, "key": key, "other": other, "dir": d}


async def _connect(plant: dict, user: str | None = USER, password: str = PASSWORD, cert: tuple | None = None) -> Client:
    client = Client(plant["url"], timeout=30)
    client.application_uri = CLIENT_URI
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    cert_file, key_file = cert or (plant["cert"], plant["key"])
    await client.set_security(
        SecurityPolicyBasic256Sha256, str(cert_file), str(key_file), mode=ua.MessageSecurityMode.SignAndEncrypt
    )
    await client.connect()
    return client


async def _gearbox(client: Client, gearbox_id: str = "GB-7"):
    idx = await client.get_namespace_index("urn:online-backlash:gearboxes")
    return await client.nodes.objects.get_child([f"{idx}:Gearboxes", f"{idx}:{gearbox_id}"]), idx


def test_browse_to_a_gearbox_and_read_what_history_json_says(plant):
    history = _history(plant["db"])

    async def read() -> dict:
        client = await _connect(plant)
        try:
            gearbox, idx = await _gearbox(client)
            names = {(await child.read_browse_name()).Name for child in await gearbox.get_children()}
            read = {name: await (await gearbox.get_child(f"{idx}:{name}")).read_data_value(False) for name in names}
            values = {name: v.Value.Value if v.StatusCode.is_good() else v.StatusCode.name for name, v in read.items()}
            play = await gearbox.get_child(f"{idx}:PlayArcmin")
            units = await (await play.get_child("0:EngineeringUnits")).read_value()
            eu_range = await (await play.get_child("0:EURange")).read_value()
            hours = await (await gearbox.get_child(f"{idx}:HoursToLimit")).get_child("0:EngineeringUnits")
            source = (await play.read_data_value()).SourceTimestamp
            return {
                "values": values,
                "units": units,
                "range": eu_range,
                "hours_unit": await hours.read_value(),
                "source": source,
            }
        finally:
            await client.disconnect()

    got = asyncio.run(read())
    values = got["values"]
    latest = [e for e in history["estimates"] if e["time_unix_s"] == history["estimates"][-1]["time_unix_s"]][-1]
    assert values["PlayArcmin"] == history["play_arcmin"]  # the same double, not a rounding of it
    assert values["PlayDeg"] == latest["backlash_deg"] and values["PlayStdArcmin"] == latest["backlash_std_arcmin"]
    assert values["State"] == history["state"] == "ok" and values["StateCode"] == 0
    assert values["StateReason"] == history["state_reason"]
    assert values["WarnArcmin"] == 13.0 and values["LimitArcmin"] == 21.0
    assert values["HoursToLimit"] == history["forecast_hours_to_limit"]
    assert values["PlayObservable"] is True
    assert values["LastEstimateTime"].timestamp() == pytest.approx(latest["time_unix_s"], abs=1e-3)
    assert got["source"].timestamp() == pytest.approx(latest["time_unix_s"], abs=1e-3)
    assert (
        values["StiffnessNmPerArcmin"] == "BadWaitingForInitialData"
    )  # no torque column: not known, no number made up
    assert got["units"].UnitId == unit_id("D61") and got["units"].NamespaceUri.endswith("/units/un/cefact")
    assert got["hours_unit"].UnitId == unit_id("HUR")
    assert (got["range"].Low, got["range"].High) == (0.0, 300.0)


def test_a_subscriber_sees_the_play_and_the_state_change_while_track_adds_logs(plant):
    async def watch() -> tuple[list, list]:
        client = await _connect(plant)
        values: asyncio.Queue = asyncio.Queue()
        events: asyncio.Queue = asyncio.Queue()

        class Handler:
            def datachange_notification(self, node, val, data) -> None:
                values.put_nowait(val)

            def event_notification(self, event) -> None:
                events.put_nowait(event)

        try:
            gearbox, idx = await _gearbox(client)
            play = await gearbox.get_child(f"{idx}:PlayArcmin")
            subscription = await client.create_subscription(100, Handler())
            await subscription.subscribe_data_change(play)
            alarm_type = await client.nodes.base_event_type.get_child(
                [
                    "0:ConditionType",
                    "0:AcknowledgeableConditionType",
                    "0:AlarmConditionType",
                    "0:DiscreteAlarmType",
                    "0:OffNormalAlarmType",
                    f"{idx}:BacklashStateAlarmType",
                ]
            )
            await subscription.subscribe_events(ua.ObjectIds.Server, alarm_type)
            first = await asyncio.wait_for(values.get(), WAIT_S)  # the current value comes first
            track = asyncio.create_task(asyncio.to_thread(_track, plant["db"], 40, 50, 59))
            seen, states = [first], []
            while (
                not states
                or states[-1].State != "warning"
                or not track.done()
                or seen[-1] != _history(plant["db"])["play_arcmin"]
            ):
                getters = {asyncio.ensure_future(values.get()): seen, asyncio.ensure_future(events.get()): states}
                done, pending = await asyncio.wait(
                    [*getters, track] if not track.done() else getters,
                    timeout=WAIT_S,
                    return_when=asyncio.FIRST_COMPLETED,
                )
                for future in pending:
                    if future is not track:
                        future.cancel()
                assert done, f"nothing within {WAIT_S} s: values {seen}, events {states}"
                for future in done:
                    if future is track:
                        future.result()
                    else:
                        getters[future].append(future.result())
            return seen, states
        finally:
            await client.disconnect()

    seen, states = asyncio.run(watch())
    history = _history(plant["db"])
    assert seen[-1] == history["play_arcmin"] > seen[0]  # the play grew as the logs came in
    event = states[-1]
    assert (
        (event.Gearbox, event.State, event.SourceName)
        == ("GB-7", "warning", "GB-7")
        == ("GB-7", history["state"], "GB-7")
    )
    assert event.Severity == 600 and "GB-7: warning" in event.Message.Text


def test_a_wrong_password_an_unknown_user_no_login_and_an_untrusted_certificate_are_refused(plant):
    async def refused(**how) -> str:
        try:
            client = await _connect(plant, **how)
        except (ua.UaStatusCodeError, ua.UaError, ConnectionError, asyncio.TimeoutError, TimeoutError) as exc:
            return type(exc).__name__ + str(exc)
        await client.disconnect()
        return ""

    assert "BadUserAccessDenied" in asyncio.run(refused(password="wrong"))
    assert "BadUserAccessDenied" in asyncio.run(refused(user="intruder"))
    assert "BadIdentityTokenRejected" in asyncio.run(refused(user=None))  # anonymous only with --allow-anonymous
    assert "BadCertificateUntrusted" in asyncio.run(refused(cert=plant["other"]))  # not in --trust: no secure channel


def test_the_server_is_read_only(plant):
    async def try_to_write() -> list[str]:
        client = await _connect(plant)
        errors = []
        try:
            gearbox, idx = await _gearbox(client)
            for attempt in (
                (await gearbox.get_child(f"{idx}:PlayArcmin")).write_value(
                    ua.DataValue(ua.Variant(1.0, ua.VariantType.Double))
                ),
                (await gearbox.get_child(f"{idx}:State")).write_value(
                    ua.DataValue(ua.Variant("ok", ua.VariantType.String))
                ),
                gearbox.add_variable(idx, "Injected", 1.0),
                gearbox.delete(),
            ):
                try:
                    await attempt
                    errors.append("")
                except ua.UaStatusCodeError as exc:
                    errors.append(type(exc).__name__)
            return errors
        finally:
            await client.disconnect()

    errors = asyncio.run(try_to_write())
    assert all(e in ("BadUserAccessDenied", "BadNotWritable") for e in errors), errors


def test_a_given_certificate_and_anonymous_sessions_when_allowed(plant):
    """The certificate made on the first run, given with --cert/--key; --allow-anonymous lets a client in without
    a login, and it still cannot write."""
    pki = plant["dir"] / "pki"
    argv = ("--db", str(plant["db"]), "--cert", str(pki / "server-cert.der"), "--key", str(pki / "server-key.pem"))
    with _serving(plant["dir"], *argv, "--allow-anonymous", "--max-age-h", "1e6") as (url, line):
        assert f"certificate {pki / 'server-cert.der'}" in line and "anonymous sessions" in line

        async def anonymous() -> tuple[str, str]:
            client = await _connect({**plant, "url": url}, user=None)
            try:
                gearbox, idx = await _gearbox(client)
                state = await (await gearbox.get_child(f"{idx}:State")).read_value()
                try:
                    await (await gearbox.get_child(f"{idx}:PlayArcmin")).write_value(1.0)
                    refused = ""
                except ua.UaStatusCodeError as exc:
                    refused = type(exc).__name__
                return state, refused
            finally:
                await client.disconnect()

        state, refused = asyncio.run(anonymous())
    assert state == _history(plant["db"])["state"] and refused in ("BadUserAccessDenied", "BadNotWritable")


def test_a_file_that_is_no_certificate_and_a_taken_port_are_one_line_errors(plant, tmp_path, capsys):
    from online_backlash.cli import main

    bad = tmp_path / "cert.der"
    bad.write_text("not a certificate")
    argv = ["opcua", "--db", str(plant["db"]), "--cert", str(bad), "--key", str(bad), "--allow-anonymous"]
    assert main([*argv, "--endpoint", f"opc.tcp://127.0.0.1:{_free_port()}"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {bad}: not a usable certificate and private key") and err.count("\n") == 1
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert (
            main(
                [
                    "opcua",
                    "--db",
                    str(plant["db"]),
                    "--security",
                    "none",
                    "--allow-anonymous",
                    "--endpoint",
                    f"opc.tcp://127.0.0.1:{port}",
                ]
            )
            == 1
        )
    err = capsys.readouterr().err
    assert err.startswith(f"error: --endpoint opc.tcp://127.0.0.1:{port}: cannot listen there") and err.count("\n") == 1


def test_a_password_without_message_security_is_warned_of(tmp_path, capsys, monkeypatch):
    from online_backlash.cli import main

    monkeypatch.setenv("ONLINE_BACKLASH_OPCUA_PASSWORD", PASSWORD)
    assert main(["opcua", "--db", str(tmp_path / "none.db"), "--security", "none", "--user", USER]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "warning: --security none: the password of --user crosses the network in plain text"
    assert lines[1].startswith("error: no history store at ")


def _store_one_gearbox(db: str, gearbox_id: str, play_arcmin: float) -> None:
    """A gearbox with levels 18 and 21 arcmin and one observable estimate of ``play_arcmin``, with a stiffness."""
    import time

    from fleet_store import fill_gearbox

    from online_backlash.history.store import HistoryStore

    with HistoryStore(db, create=True) as store:
        fill_gearbox(store, gearbox_id, [play_arcmin], time.time() - 30, False, stiffness_nm_per_arcmin=4.25)


def _store_gone() -> list:
    from online_backlash.errors import HistoryError

    raise HistoryError("the server closed the connection")


def test_the_server_in_process_over_either_store(store_db):
    """PlantServer as a library over SQLite and PostgreSQL (read-only), no message security, an anonymous client:
    the state and the stiffness are the store's, a gearbox that appears in the store gets its object and a
    state event at the next read, and a read that fails leaves the values shown, marked uncertain."""
    from online_backlash.opcua.server import PlantServer
    from online_backlash.opcua.settings import OpcuaSecurity
    from online_backlash.web import open_read_only

    _store_one_gearbox(store_db, "GB-9", 19.5)
    url = f"opc.tcp://127.0.0.1:{_free_port()}/online-backlash"
    events: list = []
    errors: list = []

    async def serve_and_read() -> tuple[dict, str]:
        with open_read_only(store_db) as store:
            security = OpcuaSecurity("none", allow_anonymous=True)
            server = PlantServer(store, url, security, on_event=events.append, on_error=errors.append)
            await server.start()
            try:
                async with Client(url, timeout=30) as client:
                    gearbox, idx = await _gearbox(client, "GB-9")
                    names = ("State", "StateCode", "PlayArcmin", "StiffnessNmPerArcmin")
                    values = {n: await (await gearbox.get_child(f"{idx}:{n}")).read_value() for n in names}
                    await asyncio.to_thread(_store_one_gearbox, store_db, "GB-10", 22.0)
                    await server.refresh()
                    new, _ = await _gearbox(client, "GB-10")
                    new_state = await (await new.get_child(f"{idx}:State")).read_value()
                    play = await gearbox.get_child(f"{idx}:PlayArcmin")
                    server.reader.read = _store_gone  # the database goes away: the values stay, marked uncertain
                    await server.refresh()
                    gone = await play.read_data_value(raise_on_bad_status=False)
                    del server.reader.read  # back: the class's method
                    await server.refresh()
                    back = await play.read_data_value(raise_on_bad_status=False)
                    seen = [(d.Value.Value, d.StatusCode.name) for d in (gone, back)]
                    return values, new_state, seen
            finally:
                await server.stop()

    values, new_state, seen = asyncio.run(serve_and_read())
    assert values == {"State": "warning", "StateCode": 1, "PlayArcmin": 19.5, "StiffnessNmPerArcmin": 4.25}
    assert new_state == "alarm" and [(e.gearbox, e.state) for e in events] == [("GB-10", "alarm")]
    assert seen == [(19.5, "UncertainLastUsableValue"), (19.5, "Good")]
    assert errors == ["the server closed the connection", None]

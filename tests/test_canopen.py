"""CANopen servo drives: EDS files written by the ``canopen`` library, TPDOs sent by its ``LocalNode``
after SYNC (or event-driven: on change or on their timer, no SYNC) on a python-can ``virtual`` bus,
recorded with python-can's writers, then estimated, listened to, inspected; damaged frames counted;
the load encoder on a second node or on 0x60E4."""

from __future__ import annotations

import json
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from live_run import run_live

from online_backlash.cli import main
from online_backlash.codecs.canopen import CanopenLayout, SyncPipeline, canopen_pipeline
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.replay import open_log
from online_backlash.simulation.rig import RigRecording, simulate_rig

MOTOR_BITS, LOAD_BITS = 14, 17
SYNC_OVERFLOW = 16


@pytest.fixture(scope="module")
def rec() -> RigRecording:
    return simulate_rig(
        duration_s=4.0, rate_hz=1000.0, reversal_s=(0.4, 0.8), seed=5, motor_bits=MOTOR_BITS, load_bits=LOAD_BITS
    )


def _var(
    name: str, index: int, subindex: int, data_type: int, default: int | None = None, relative: str | None = None
) -> ODVariable:
    var = ODVariable(name, index, subindex)
    var.data_type = data_type
    var.access_type = "rw"
    var.pdo_mappable = index >= 0x6000
    var.default = default
    if relative is not None:
        var.default_raw = relative  # "$NODEID+0x180": the COB-ID follows the node-ID it is imported with
    return var


def _record(name: str, index: int, members: list[ODVariable], array: bool = False) -> ODRecord | ODArray:
    obj = ODArray(name, index) if array else ODRecord(name, index)
    for member in members:
        obj.add_member(member)
    return obj


def write_eds(
    path: Path,
    node: int,
    mapped: list[tuple[int, int]],
    *,
    resolution: int | None,
    trans_type: int = 1,
    sync: bool = True,
    second: list[tuple[int, int]] | None = None,
    factor_group: dict[int, tuple[int, int]] | None = None,
) -> Path:
    """A servo drive's EDS written by ``canopen.export_od``: TPDO1 (COB-ID $NODEID+0x180) maps ``mapped`` objects (32
    bits each), TPDO2 ($NODEID+0x280) the ``second`` ones, both of transmission type ``trans_type``; ``factor_group``
    gives the CiA 402 ratio objects 0x6091 (gear ratio) and 0x6092 (feed constant) as (sub 1, sub 2)."""
    od = canopen.ObjectDictionary()
    u8, u32, i32 = datatypes.UNSIGNED8, datatypes.UNSIGNED32, datatypes.INTEGER32
    if sync:
        od.add_object(_var("COB-ID SYNC", 0x1005, 0, u32, 0x80))
        od.add_object(_var("Synchronous counter overflow value", 0x1019, 0, u8, SYNC_OVERFLOW))
    for n, objects in enumerate([mapped] if second is None else [mapped, second]):
        comm, mapping = 0x1800 + n, 0x1A00 + n
        od.add_object(
            _record(
                f"Transmit PDO {n + 1} communication parameter",
                comm,
                [
                    _var("Highest sub-index supported", comm, 0, u8, 2),
                    _var(
                        "COB-ID used by TPDO",
                        comm,
                        1,
                        u32,
                        0x180 + 0x100 * n + node,
                        relative=f"$NODEID+0x{0x180 + 0x100 * n:X}",
                    ),
                    _var("Transmission type", comm, 2, u8, trans_type),
                ],
            )
        )
        entries = [
            _var(f"Application object {i + 1}", mapping, i + 1, u32, (index << 16) | (sub << 8) | 32)
            for i, (index, sub) in enumerate(objects)
        ]
        od.add_object(
            _record(
                f"Transmit PDO {n + 1} mapping parameter",
                mapping,
                [_var("Number of mapped objects", mapping, 0, u8, len(objects)), *entries],
            )
        )
    od.add_object(_var("Position actual value", 0x6064, 0, i32, 0))
    od.add_object(
        _record(
            "Additional position actual value",
            0x60E4,
            [
                _var("Highest sub-index supported", 0x60E4, 0, u8, 2),
                _var("Additional position actual value 1", 0x60E4, 1, i32, 0),
                _var("Additional position actual value 2", 0x60E4, 2, i32, 0),
            ],
            array=True,
        )
    )
    if resolution is not None:
        od.add_object(
            _record(
                "Position encoder resolution",
                0x608F,
                [
                    _var("Highest sub-index supported", 0x608F, 0, u8, 2),
                    _var("Encoder increments", 0x608F, 1, u32, resolution),
                    _var("Motor revolutions", 0x608F, 2, u32, 1),
                ],
            )
        )
    names = {
        0x6091: ("Gear ratio", "Motor shaft revolutions", "Driving shaft revolutions"),
        0x6092: ("Feed constant", "Feed", "Shaft revolutions"),
    }
    for index, (top, bottom) in (factor_group or {}).items():
        name, first, second_name = names[index]
        od.add_object(
            _record(
                name,
                index,
                [
                    _var("Number of entries", index, 0, u8, 2),
                    _var(first, index, 1, u32, top),
                    _var(second_name, index, 2, u32, bottom),
                ],
            )
        )
    canopen.export_od(od, str(path))
    return path


class HardwareClock:
    """The bus a canopen Network sends through, stamping each frame with the simulated time (as an adapter's hardware
    clock)."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.now = 0.0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        msg.timestamp = self.now
        self.bus.send(msg, timeout)


def int32(count: np.ndarray) -> list[int]:
    """Counts as a drive's INTEGER32 position: rolling over at 2**31."""
    return [int(c) for c in (count.astype(np.int64) + 2**31) % 2**32 - 2**31]


def counts(angle_deg: np.ndarray, cpr: int) -> np.ndarray:
    """Encoder counts placed so that half the run lies past the 32-bit rollover."""
    c = np.round(angle_deg / 360.0 * cpr).astype(np.int64)
    return c - int(np.median(c)) + 2**31


class Rig:
    """Drives (canopen ``LocalNode``) on a virtual bus sending their TPDO after each SYNC of the test's SYNC
    producer."""

    def __init__(self, channel: str, nodes: dict[int, Path]) -> None:
        self.tx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        self.clock = HardwareClock(self.tx)
        self.network = canopen.Network(self.clock)
        self.nodes = {}
        for node_id, eds in nodes.items():
            node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
            self.network.add_node(node)
            node.tpdo.read(from_od=True)
            self.nodes[node_id] = node

    def play(
        self, rec: RigRecording, values: dict[tuple[int, int, int], list[int]], t0: float = 1.7e9, hook=None
    ) -> None:
        """For sample k: SYNC (counter 1..16), then each node's TPDO1 with ``values[(node, index, sub)][k]``."""
        for k, t in enumerate(rec.time_s.tolist()):
            self.clock.now = t0 + t
            if hook is None or hook(k, "sync"):
                self.network.sync.transmit(k % SYNC_OVERFLOW + 1)
            for node_id, node in self.nodes.items():
                pdo = node.tpdo[1]
                for var in pdo:
                    var.raw = values[(node_id, var.index, var.subindex)][k]
                self.clock.now = t0 + t + 50e-6
                if hook is None or hook(k, node_id):
                    pdo.transmit()

    def play_events(
        self,
        rec: RigRecording,
        values: dict[tuple[int, int, int], list[int]],
        offsets_s: dict[int, float],
        on_change: bool = False,
        t0: float = 1.7e9,
    ) -> None:
        """Event-driven TPDOs, no SYNC: at sample k each node sends every TPDO on its own timer (``offsets_s[node]``
        after the sample, 10 us between its PDOs) or, ``on_change``, only the PDOs whose value changed since they were
        last sent."""
        sent: dict[tuple[int, int], list[int]] = {}
        for k, t in enumerate(rec.time_s.tolist()):
            for node_id, node in self.nodes.items():
                for number, pdo in enumerate(p for p in node.tpdo.map.values() if p.enabled):
                    now = [values[(node_id, var.index, var.subindex)][k] for var in pdo]
                    if on_change and sent.get((node_id, number)) == now:
                        continue
                    for var, value in zip(pdo, now):
                        var.raw = value
                    self.clock.now = t0 + t + offsets_s[node_id] + number * 1e-5
                    pdo.transmit()
                    sent[(node_id, number)] = now

    def close(self) -> None:
        self.tx.shutdown()


def record(channel: str, send, path: Path, extra: list[can.Message] = ()) -> list[can.Message]:
    """Receive what ``send()`` puts on the bus and write it with python-can's writer for ``path`` (by suffix)."""
    rx = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    try:
        send()
        frames = list(extra)
        while (msg := rx.recv(timeout=0)) is not None:
            frames.append(msg)
    finally:
        rx.shutdown()
    frames.sort(key=lambda m: m.timestamp)
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return frames


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("eds")
    return {
        # motor drive: 0x6064 and the load encoder on 0x60E4.1 in one TPDO; 0x608F gives the motor's counts per
        # revolution
        "both": write_eds(folder / "drive_both.eds", 3, [(0x6064, 0), (0x60E4, 1)], resolution=2**MOTOR_BITS),
        # two identical drives (one EDS): node 3 the motor, node 4 an encoder on the load shaft
        "motor": write_eds(folder / "drive.eds", 3, [(0x6064, 0)], resolution=2**MOTOR_BITS),
        "load": write_eds(folder / "encoder.eds", 4, [(0x6064, 0)], resolution=2**LOAD_BITS),
        "rtr": write_eds(folder / "rtr.eds", 3, [(0x6064, 0)], resolution=2**MOTOR_BITS, trans_type=253),
        "no_cpr": write_eds(folder / "no_cpr.eds", 3, [(0x6064, 0)], resolution=None),
    }


def one_drive(eds: Path, load_cpr: int = 2**LOAD_BITS) -> list[str]:
    """The options of a log of one drive, node 3, whose load encoder (0x60E4.1) has ``load_cpr`` counts per turn."""
    return ["--eds", str(eds), "--node", "3", "--load-cpr", str(load_cpr)]


def two_drives(motor_eds: Path, load_eds: Path) -> list[str]:
    """The options of a log of two drives: the motor's, node 3, and the load encoder's, node 4, each its dictionary."""
    return ["--eds", str(motor_eds), "--node", "3", "--load-node", "4", "--load-eds", str(load_eds)]


def one_node_values(rec: RigRecording) -> dict[tuple[int, int, int], list[int]]:
    return {
        (3, 0x6064, 0): int32(counts(rec.motor_deg, 2**MOTOR_BITS)),
        (3, 0x60E4, 1): int32(counts(rec.load_deg, 2**LOAD_BITS)),
    }


def two_node_values(rec: RigRecording) -> dict[tuple[int, int, int], list[int]]:
    return {
        (3, 0x6064, 0): int32(counts(rec.motor_deg, 2**MOTOR_BITS)),
        (4, 0x6064, 0): int32(counts(rec.load_deg, 2**LOAD_BITS)),
    }


def test_the_positions_roll_over_within_the_run(rec):
    for values in one_node_values(rec).values():
        assert min(values) < -(2**30) and max(values) > 2**30  # INTEGER32 wraps from 2**31 - 1 to -2**31


def test_the_eds_is_the_library_s_and_the_mapping_comes_from_it(drives):
    layout = CanopenLayout.from_files(drives["both"], 3, load_cpr=2**LOAD_BITS)
    assert (layout.motor.pdo.cob_id, layout.motor.obj.index, layout.motor.obj.bit_offset) == (0x183, 0x6064, 0)
    assert (layout.load.pdo.cob_id, layout.load.obj.index, layout.load.obj.subindex, layout.load.obj.bit_offset) == (
        0x183,
        0x60E4,
        1,
        32,
    )
    assert (
        layout.motor.counts_per_rev == 2**MOTOR_BITS
        and layout.sync_cob_id == 0x80
        and layout.sync_overflow == SYNC_OVERFLOW
    )
    # the same EDS for another node: $NODEID in the file moves the COB-ID
    assert CanopenLayout.from_files(drives["motor"], 3, load_node=5, load_cpr=100).load.pdo.cob_id == 0x185
    assert "$NODEID" in drives["motor"].read_text()


def test_a_dcf_s_parameter_values_win_over_the_eds_defaults(tmp_path, drives):
    """A DCF (the drive as commissioned) written by ``canopen.export_od``: its COB-ID and resolution are the ones
    used."""
    od = canopen.import_od(str(drives["both"]), 3)
    od[0x1800][1].value = 0x283
    od[0x608F][1].value = 4000
    dcf = tmp_path / "drive.dcf"
    canopen.export_od(od, str(dcf))
    layout = CanopenLayout.from_files(dcf, 3, load_cpr=1000)
    assert "ParameterValue" in dcf.read_text()
    assert layout.motor.pdo.cob_id == layout.load.pdo.cob_id == 0x283 and layout.motor.counts_per_rev == 4000


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_estimate_a_recorded_log_of_one_drive_with_0x60e4(tmp_path, capsys, rec, drives, suffix):
    rig = Rig(f"co-{suffix}", {3: drives["both"]})
    log = tmp_path / f"run{suffix}"
    try:
        frames = record(f"co-{suffix}", lambda: rig.play(rec, one_node_values(rec)), log)
    finally:
        rig.close()
    assert len(frames) == 2 * rec.time_s.size
    argv = ["estimate", str(log), *one_drive(drives["both"]), "--ratio", "30", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["backlash_deg"] == pytest.approx(0.5, abs=0.02)
    assert (out["frames"], out["samples"], out["corrupt"], out["skipped"], out["unpaired"], out["gaps"]) == (
        len(frames),
        rec.time_s.size,
        0,
        0,
        0,
        0,
    )
    # the samples are the rig's angles, through the 32-bit rollover, timestamped at the SYNC
    with open_log(log, eds=drives["both"], node=3, load_cpr=2**LOAD_BITS) as source:
        chunk = next(source.iter_chunks(max_samples=10**6))
    assert np.allclose(chunk.motor_deg - chunk.motor_deg[0], rec.motor_deg - rec.motor_deg[0], atol=360 / 2**MOTOR_BITS)
    assert np.allclose(chunk.load_deg - chunk.load_deg[0], rec.load_deg - rec.load_deg[0], atol=360 / 2**LOAD_BITS)
    assert np.allclose(chunk.time_s - 1.7e9, rec.time_s, atol=1e-5)


def test_a_second_node_as_load_encoder_and_damaged_frames_counted(tmp_path, capsys, rec, drives):
    rig = Rig("co-two", {3: drives["motor"], 4: drives["load"]})
    lost_sync, lost_pdo, short_pdo = 1000, 2000, 3000

    def hook(k: int, what: int | str) -> bool:
        return not ((k == lost_sync and what == "sync") or (k == lost_pdo and what == 4))

    foreign = [
        can.Message(arbitration_id=0x703, data=[5], timestamp=1.7e9 + 0.5 + i * 1e-4, is_extended_id=False)
        for i in range(7)
    ]
    log = tmp_path / "two.blf"
    try:
        frames = record("co-two", lambda: rig.play(rec, two_node_values(rec), hook=hook), log, extra=foreign)
    finally:
        rig.close()
    # one PDO of the motor node cut short (DLC 3), written again
    frames = [
        m
        if not (m.arbitration_id == 0x183 and abs(m.timestamp - 1.7e9 - rec.time_s[short_pdo]) < 1e-4)
        else can.Message(arbitration_id=0x183, data=m.data[:3], timestamp=m.timestamp, is_extended_id=False)
        for m in frames
    ]
    with can.Logger(str(log)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    argv = ["estimate", str(log), *two_drives(drives["motor"], drives["load"]), "--ratio", "30", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["backlash_deg"] == pytest.approx(0.5, abs=0.02)
    n = rec.time_s.size
    # each costs a sample and a gap (the SYNC counter jumps). Lost SYNC: its two PDOs have no period (unpaired 2);
    # lost load PDO: its SYNC and motor PDO unpaired (2); short PDO: corrupt, its SYNC and load PDO unpaired (2)
    assert out["corrupt"] == 1 and out["skipped"] == len(foreign) and out["unpaired"] == 6 and out["gaps"] == 3
    assert out["samples"] == n - 3
    assert out["frames"] == len(frames) == out["skipped"] + out["corrupt"] + out["unpaired"] + 3 * out["samples"]
    # track and diagnose read it the same way
    nodes = ["--eds", str(drives["motor"]), "--node", "3", "--load-node", "4", "--load-eds", str(drives["load"])]
    assert (
        main(
            [
                "track",
                str(log),
                *nodes,
                "--ratio",
                "30",
                "--db",
                str(tmp_path / "wear.db"),
                "--gearbox",
                "gb1",
                "--every",
                "1",
                "--json",
            ]
        )
        == 0
    )
    tracked = json.loads(capsys.readouterr().out)
    # (4 s of data are too short for the tracker's warm start: it says so, and counts the log as read)
    assert (
        tracked["samples_fed"] == n - 3
        and tracked["counters"]["unpaired"] == 6
        and tracked["counters"]["frames"] == len(frames)
    )
    assert main(["diagnose", str(log), *nodes, "--ratio", "30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["corrupt"] == 1
    # the CAN IDs of inspect, named by the dictionaries
    assert main(["inspect", str(log), *two_drives(drives["motor"], drives["load"]), "--json"]) == 0
    ids = {i["id"]: i for i in json.loads(capsys.readouterr().out)["can_ids"]}
    assert ids["0x080"]["message"] == "SYNC" and ids["0x080"]["frames"] == n - 1
    assert ids["0x183"]["message"] == "TxPDO1_node3: 0x6064.0 Position actual value"
    assert ids["0x184"]["message"] == "TxPDO1_node4: 0x6064.0 Position actual value"
    assert ids["0x703"]["message"] == "heartbeat node 3"


@pytest.mark.parametrize("trigger", ["sync", "event"])
def test_listen_can_live_on_a_virtual_bus_replays_to_the_same_estimate(
    tmp_path, capsys, rec, drives, event_drives, trigger
):
    channel = f"co-live-{trigger}"
    eds = drives["both"] if trigger == "sync" else event_drives["both"]

    def send(_):
        rig = Rig(channel, {3: eds})
        try:
            if trigger == "sync":
                rig.play(rec, one_node_values(rec))
            else:
                rig.play_events(rec, one_node_values(rec), {3: 5e-5})
        finally:
            rig.close()  # then Ctrl-C: the frames still waiting on the bus are learned too

    raw = tmp_path / "raw"
    argv = [
        "listen",
        "can",
        "--interface",
        "virtual",
        "--channel",
        channel,
        *one_drive(eds),
        "--ratio",
        "30",
        "--raw-log",
        str(raw),
        "--json",
    ]
    assert run_live(argv, send) == 0
    live = json.loads(capsys.readouterr().out)
    per_sample = 2 if trigger == "sync" else 1  # SYNC + PDO, or the event-driven PDO alone
    assert (
        live["samples"] == rec.time_s.size and live["frames"] == per_sample * rec.time_s.size and live["unpaired"] == 0
    )
    assert live["backlash_deg"] == pytest.approx(0.5, abs=0.02)
    assert main(["estimate", str(raw), *one_drive(eds), "--ratio", "30", "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert replayed["backlash_deg"] == live["backlash_deg"] and replayed["samples"] == live["samples"]


E35_RESOLUTION = 2000  # 0x608F of the canopen package's sample CiA 402 drive, examples/eds/e35.eds


@pytest.fixture(scope="module")
def e35_like(tmp_path_factory) -> dict[str, Path]:
    """Drives whose factor group is the one of the ``canopen`` package's sample drive ``e35.eds``: feed constant
    0x6092 = 1/1 and gear ratio 0x6091 = 1/1 (the unit defaults), position encoder resolution 0x608F = 2000/1
    (written here from the library's objects: the wheel does not ship the file)."""
    folder = tmp_path_factory.mktemp("e35")
    defaults = {0x6091: (1, 1), 0x6092: (1, 1)}
    return {
        "e35": write_eds(
            folder / "e35_like.eds", 3, [(0x6064, 0), (0x60E4, 1)], resolution=E35_RESOLUTION, factor_group=defaults
        ),
        "no_resolution": write_eds(
            folder / "feed_only.eds", 3, [(0x6064, 0), (0x60E4, 1)], resolution=None, factor_group=defaults
        ),
        "set_feed": write_eds(
            folder / "set_feed.eds",
            3,
            [(0x6064, 0)],
            resolution=E35_RESOLUTION,
            factor_group={0x6092: (3600, 1), 0x6091: (2, 1)},
        ),
    }


def test_a_feed_constant_at_its_unit_default_takes_the_encoder_resolution(tmp_path, capsys, rec, e35_like):
    """e35.eds read as 1 count per revolution gave ``backlash: nan deg`` with exit 0; 0x608F gives the real play."""
    layout = CanopenLayout.from_files(e35_like["e35"], 3, load_cpr=2**LOAD_BITS)
    assert layout.motor.counts_per_rev == E35_RESOLUTION
    assert (
        CanopenLayout.from_files(e35_like["set_feed"], 3, load_node=4, load_cpr=100).motor.counts_per_rev == 1800
    )  # 3600 / 2
    rig = Rig("co-e35", {3: e35_like["e35"]})
    log = tmp_path / "e35.blf"
    values = {
        (3, 0x6064, 0): int32(counts(rec.motor_deg, E35_RESOLUTION)),
        (3, 0x60E4, 1): int32(counts(rec.load_deg, 2**LOAD_BITS)),
    }
    try:
        record("co-e35", lambda: rig.play(rec, values), log)
    finally:
        rig.close()
    assert main(["estimate", str(log), *one_drive(e35_like["e35"]), "--ratio", "30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["backlash_deg"] == pytest.approx(0.5, abs=0.05)
    assert main(["estimate", str(log), *one_drive(e35_like["no_resolution"], 4096), "--ratio", "30"]) == 1
    err = capsys.readouterr().err
    assert err == (
        f"error: {e35_like['no_resolution']}: node 3: no counts per revolution in the dictionary (the feed constant "
        "0x6092 is 1/1, "
        "the unit default, and no position encoder resolution 0x608F; a set feed constant 0x6092 / gear ratio "
        "0x6091 would give "
        "them): give --motor-cpr\n"
    )


def test_bad_dictionaries_and_nodes_name_the_file_and_the_object(tmp_path, capsys, drives):
    log = tmp_path / "empty.asc"
    with can.Logger(str(log)) as writer:
        writer.on_message_received(can.Message(arbitration_id=0x80, data=[], timestamp=1.0, is_extended_id=False))
    cases = [
        (
            ["--eds", str(drives["no_cpr"]), "--node", "3", "--load-node", "4"],
            f"{drives['no_cpr']}: node 3: no counts per revolution",
            "--motor-cpr",
        ),
        (
            ["--eds", str(drives["motor"]), "--node", "3"],
            f"{drives['motor']}: node 3: object 0x60E4 is not mapped",
            "TxPDO1_node3: 0x6064.0",
        ),
        (
            ["--eds", str(drives["rtr"]), "--node", "3", "--load-node", "4"],
            f"{drives['rtr']}: node 3: TxPDO1_node3 (0x1800) has transmission type 253",
            "neither synchronous (0-240) nor event-driven (254, 255)",
        ),
        (
            ["--eds", str(tmp_path / "missing.eds"), "--node", "3"],
            f"{tmp_path / 'missing.eds'}: no such object dictionary",
            "",
        ),
        (["--eds", str(drives["both"])], "give --node N", ""),
        (
            ["--eds", str(drives["both"]), "--node", "3"],
            "0x60E4.1 Additional position actual value 1 of node 3: give its counts per load revolution",
            "",
        ),
    ]
    for options, message, also in cases:
        assert main(["estimate", str(log), *options, "--ratio", "30"]) != 0
        err = capsys.readouterr().err
        assert err.startswith("error: ") and message in err and also in err and "Traceback" not in err, err
    bad = tmp_path / "broken.eds"
    bad.write_text("[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007\nDefaultValue=not-a-number\n")
    with pytest.raises(LogFormatError, match=r"broken\.eds: cannot read the object dictionary"):
        CanopenLayout.from_files(bad, 3)
    with pytest.raises(InvalidParameterError, match=r"node-ID is 1\.\.127"):
        CanopenLayout.from_files(drives["both"], 200)
    with pytest.raises(SystemExit) as usage:  # argparse: a usage error
        main(["estimate", str(log), "--eds", str(drives["both"]), "--node", "300", "--ratio", "30"])
    assert usage.value.code == 2
    assert "expected a number 1..127" in capsys.readouterr().err


def test_sync_pipeline_frame_by_frame_counts_every_frame(drives):
    """The rules one frame at a time: a sample per complete SYNC period, a repeated PDO, a bad SYNC, extended IDs."""
    layout = CanopenLayout.from_files(drives["motor"], 3, load_node=4, load_eds=drives["load"])
    pipe = SyncPipeline(layout)

    def frame(cob_id: int, data: bytes, t: float, extended: bool = False) -> can.Message:
        return can.Message(arbitration_id=cob_id, data=data, timestamp=t, is_extended_id=extended)

    motor, load = (4096).to_bytes(4, "little", signed=True), (-32768).to_bytes(4, "little", signed=True)
    rows = [
        pipe.feed_row(f)
        for f in [
            frame(0x80, b"\x01", 0.0),
            frame(0x183, motor, 0.0001),
            frame(0x184, load, 0.0002),  # a sample
            frame(0x80, b"\x02", 0.001),
            frame(0x183, motor, 0.0011),
            frame(0x183, motor, 0.0012),
            frame(0x184, load, 0.0013),  # a repeat
            frame(0x80, b"\x01\x02", 0.002),  # SYNC with 2 bytes: corrupt
            frame(0x183, motor, 0.0021),  # no period: unpaired
            frame(0x183, motor, 0.0022, extended=True),  # an extended ID: not ours
            frame(0x80, b"\x04", 0.003),  # left open at the end: unpaired
        ]
    ]
    samples = [r for r in rows if r is not None]
    assert samples[0] == (0.0, 90.0, -90.0, 0, False) and samples[1][:4] == (0.001, 90.0, -90.0, 1)
    pipe.flush()
    c = pipe.counters
    assert (c.frames, c.samples, c.corrupt, c.skipped, c.unpaired) == (11, 2, 1, 1, 3)
    assert c.frames == c.skipped + c.corrupt + c.unpaired + pipe.frames_per_sample * c.samples


def test_track_listen_can_opens_the_canopen_source(tmp_path, capsys, drives):
    """``track --listen can --eds``: the CANopen live source on the bus (here a silent one: the timeout says where it
    listened)."""
    argv = [
        "track",
        "--listen",
        "can",
        "--interface",
        "virtual",
        "--channel",
        "co-silent",
        *one_drive(drives["both"]),
        "--ratio",
        "30",
        "--db",
        str(tmp_path / "wear.db"),
        "--gearbox",
        "gb1",
        "--raw-log",
        str(tmp_path / "raw"),
        "--timeout",
        "0.3",
        "--quiet",
    ]
    assert main(argv) != 0
    err = capsys.readouterr().err
    listening, error = err.splitlines()
    assert listening == "can virtual co-silent: listening; Ctrl-C ends the run with its summary"
    assert error.startswith("error: nothing received for 0.3 s on CAN") and "Traceback" not in err, err
    assert main([*argv[:11], *argv[13:]]) != 0  # no --load-cpr for 0x60E4: the error names the object and the file
    assert f"{drives['both']}: the load angle is 0x60E4.1" in capsys.readouterr().err


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.lists(
        st.tuples(
            st.sampled_from([0x80, 0x183, 0x184, 0x703, 0x7FF]),
            st.binary(max_size=8),
            st.booleans(),
            st.floats(0, 1e-3),
        ),
        max_size=60,
    )
)
def test_fuzzed_frames_are_counted_and_reconcile(drives, event_drives, frames):
    """Any frames (our COB-IDs with any length, others, extended IDs, times out of order): only counted, never raised,
    by the SYNC grouping and by the event-driven pairing alike."""
    for d in (drives, event_drives):
        _fuzz(canopen_pipeline(CanopenLayout.from_files(d["motor"], 3, load_node=4, load_eds=d["load"])), frames)


def _fuzz(pipe, frames) -> None:
    t = 0.0
    for cob_id, data, extended, dt in frames:
        t += dt - 2e-4
        row = pipe.feed_row(can.Message(arbitration_id=cob_id, data=data, timestamp=t, is_extended_id=extended))
        assert row is None or all(np.isfinite(row[:3]))
    pipe.flush()
    c = pipe.counters
    assert c.frames == len(frames) == c.skipped + c.corrupt + c.unpaired + pipe.frames_per_sample * c.samples


# -- event-driven TPDOs (transmission type 254/255): no SYNC, paired in time as the DBC path pairs two messages
# ---------


@pytest.fixture(scope="module")
def event_drives(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("eds-event")
    return {
        "both": write_eds(
            folder / "both.eds", 3, [(0x6064, 0), (0x60E4, 1)], resolution=2**MOTOR_BITS, trans_type=255, sync=False
        ),
        "split": write_eds(
            folder / "split.eds",
            3,
            [(0x6064, 0)],
            second=[(0x60E4, 1)],
            resolution=2**MOTOR_BITS,
            trans_type=254,
            sync=False,
        ),
        "motor": write_eds(
            folder / "motor.eds", 3, [(0x6064, 0)], resolution=2**MOTOR_BITS, trans_type=255, sync=False
        ),
        "load": write_eds(folder / "load.eds", 4, [(0x6064, 0)], resolution=2**LOAD_BITS, trans_type=255, sync=False),
    }


def _event_log(
    tmp_path: Path, name: str, rec: RigRecording, nodes: dict[int, Path], values, offsets_s, on_change=False
) -> tuple[Path, list]:
    rig = Rig(f"ev-{name}", nodes)
    log = tmp_path / f"{name}.blf"
    try:
        frames = record(f"ev-{name}", lambda: rig.play_events(rec, values, offsets_s, on_change), log)
    finally:
        rig.close()
    assert frames and not any(m.arbitration_id == 0x80 for m in frames)  # no SYNC on this bus
    return log, frames


EVENT_CASES = {
    # name: (drives and node-IDs, options, values, node timers' offsets from the sample (s), frames per sample)
    "one TPDO": ({3: "both"}, ["--load-cpr", str(2**LOAD_BITS)], one_node_values, {3: 5e-5}, 1),
    "two TPDOs": ({3: "split"}, ["--load-cpr", str(2**LOAD_BITS)], one_node_values, {3: 5e-5}, 2),
    "two nodes": ({3: "motor", 4: "load"}, ["--load-node", "4"], two_node_values, {3: 5e-5, 4: 6.3e-4}, 2),
}


@pytest.mark.parametrize("case", sorted(EVENT_CASES))
def test_event_driven_tpdos_on_their_timer_are_paired_in_time(tmp_path, capsys, rec, event_drives, case):
    nodes, options, values, offsets, per_sample = EVENT_CASES[case]
    paths = {node: event_drives[key] for node, key in nodes.items()}
    log, frames = _event_log(tmp_path, case.replace(" ", "-"), rec, paths, values(rec), offsets)
    eds = ["--eds", str(paths[3]), "--node", "3", *options, *(["--load-eds", str(paths[4])] if 4 in paths else [])]
    assert main(["estimate", str(log), *eds, "--ratio", "30", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    n = rec.time_s.size
    assert (out["frames"], out["samples"], out["corrupt"], out["skipped"], out["unpaired"], out["gaps"]) == (
        len(frames),
        n,
        0,
        0,
        0,
        0,
    )
    assert out["backlash_deg"] == pytest.approx(0.5, abs=0.02)
    with open_log(
        log,
        eds=paths[3],
        node=3,
        **({"load_node": 4, "load_eds": paths[4]} if 4 in paths else {"load_cpr": 2**LOAD_BITS}),
    ) as source:
        chunk = next(source.iter_chunks(max_samples=10**6))
        assert source.counters.frames == per_sample * n
    # the rig's angles through the 32-bit rollover, stamped at the earlier frame of each pair
    assert np.allclose(chunk.motor_deg - chunk.motor_deg[0], rec.motor_deg - rec.motor_deg[0], atol=360 / 2**MOTOR_BITS)
    assert np.allclose(chunk.load_deg - chunk.load_deg[0], rec.load_deg - rec.load_deg[0], atol=360 / 2**LOAD_BITS)
    assert np.allclose(chunk.time_s - 1.7e9, rec.time_s + offsets[3], atol=1e-6)


def test_event_driven_tpdos_sent_on_change_count_what_cannot_pair(tmp_path, capsys, rec, event_drives):
    """Two nodes sending only when their position changed: a value whose partner did not change (the motor at rest at a
    reversal) waits, is replaced and counted unpaired; the samples lost are gaps the estimator bridges."""
    paths = {3: event_drives["motor"], 4: event_drives["load"]}
    log, frames = _event_log(
        tmp_path, "on-change", rec, paths, two_node_values(rec), {3: 5e-5, 4: 6.3e-4}, on_change=True
    )
    argv = ["estimate", str(log), *two_drives(paths[3], paths[4]), "--ratio", "30", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(frames) < 2 * rec.time_s.size and out["unpaired"] > 0 and out["samples"] > 0.9 * rec.time_s.size
    assert out["frames"] == len(frames) == out["skipped"] + out["corrupt"] + out["unpaired"] + 2 * out["samples"]
    assert out["backlash_deg"] == pytest.approx(0.5, abs=0.02)


def test_event_driven_pairing_frame_by_frame(event_drives):
    """The DBC path's pairing rules on PDOs: within max_skew_s a pair, an orphan replaced, SYNC and others skipped, a
    short PDO corrupt."""
    layout = CanopenLayout.from_files(event_drives["motor"], 3, load_node=4, load_eds=event_drives["load"])
    assert layout.event_driven and layout.names() == {
        0x183: "TxPDO1_node3: 0x6064.0 Position actual value (motor: 0x6064.0 Position actual value)",
        0x184: "TxPDO1_node4: 0x6064.0 Position actual value (load: 0x6064.0 Position actual value)",
    }
    pipe = canopen_pipeline(layout, max_skew_s=5e-4)

    def frame(cob_id: int, data: bytes, t: float) -> can.Message:
        return can.Message(arbitration_id=cob_id, data=data, timestamp=t, is_extended_id=False)

    motor, load = (4096).to_bytes(4, "little", signed=True), (-32768).to_bytes(4, "little", signed=True)
    rows = [
        pipe.feed_row(f)
        for f in [
            frame(0x183, motor, 0.0),
            frame(0x184, load, 0.0003),  # a pair, 0.3 ms apart
            frame(0x183, motor, 0.001),
            frame(0x184, load, 0.0019),  # 0.9 ms apart: no pair, the load value waits
            frame(0x183, motor, 0.002),  # pairs with the waiting load value; the motor value of 0.001 was an orphan
            frame(0x80, b"", 0.0025),
            frame(0x184, load[:3], 0.003),  # a SYNC: not ours; a short PDO: corrupt
        ]
    ]
    samples = [r for r in rows if r is not None]
    assert [s[:3] for s in samples] == [(0.0, 90.0, -90.0), (0.0019, 90.0, -90.0)]
    pipe.flush()
    c = pipe.counters
    assert (c.frames, c.samples, c.corrupt, c.skipped, c.unpaired) == (7, 2, 1, 1, 1)
    assert c.frames == c.skipped + c.corrupt + c.unpaired + pipe.frames_per_sample * c.samples


def test_inspect_lists_the_tpdo_mapping_of_several_nodes(tmp_path, capsys, rec, drives, event_drives):
    """``inspect --eds A --node 3 --eds B --node 4``: each node's TPDOs from its own dictionary (no log needed), and
    with a log its COB-IDs named by them; one --eds serves every --node of identical drives."""
    nodes = ["--eds", str(event_drives["split"]), "--node", "3", "--eds", str(drives["load"]), "--node", "4"]
    assert main(["inspect", *nodes, "--json"]) == 0
    listed = {n["node"]: n for n in json.loads(capsys.readouterr().out)["nodes"]}
    assert [
        (p["cob_id"], p["transmission_type"], p["trigger"], [o["object"] for o in p["objects"]])
        for p in listed[3]["tpdos"]
    ] == [("0x183", 254, "event", ["0x6064.0"]), ("0x283", 254, "event", ["0x60E4.1"])]
    assert [(p["cob_id"], p["trigger"], p["objects"][0]["bit_length"]) for p in listed[4]["tpdos"]] == [
        ("0x184", "sync", 32)
    ]
    assert listed[4]["eds"] == str(drives["load"]) and listed[3]["eds"] == str(event_drives["split"])
    assert main(["inspect", *nodes]) == 0
    text = capsys.readouterr().out
    assert "node 3 (" in text and "0x283   254 (event)  0x60E4.1 Additional position actual value 1 [32 bit]" in text
    # a log of two event-driven nodes: its COB-IDs named, the mapping listed beside them; one --eds for two --node
    log, _ = _event_log(
        tmp_path,
        "inspect",
        rec,
        {3: event_drives["motor"], 4: event_drives["motor"]},
        two_node_values(rec),
        {3: 5e-5, 4: 3e-4},
    )
    assert main(["inspect", str(log), "--eds", str(event_drives["motor"]), "--node", "3", "--node", "4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    ids = {i["id"]: i["message"] for i in out["can_ids"]}
    assert ids == {
        "0x183": "TxPDO1_node3: 0x6064.0 Position actual value",
        "0x184": "TxPDO1_node4: 0x6064.0 Position actual value",
    }
    assert [n["node"] for n in out["nodes"]] == [3, 4] and out["nodes"][1]["tpdos"][0]["cob_id"] == "0x184"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--eds", "{a}", "--eds", "{b}", "--node", "3"],
            "2 --eds for 1 --node: give one --eds per --node, or one for all",
        ),
        (["--eds", "{a}", "--node", "3", "--node", "3"], "node-ID 3 given twice"),
        (["--eds", "{a}"], "give --node N"),
        ([], "give a FILE to inspect, or --eds FILE --node N"),
        (["--eds", "{a}", "--node", "3", "--load-eds", "{b}"], "--load-eds is the dictionary of --load-node"),
        (["--eds", "{missing}", "--node", "3"], "{missing}: no such object dictionary"),
    ],
)
def test_inspect_eds_errors_say_what_to_give(tmp_path, capsys, drives, argv, message):
    paths = {"a": drives["motor"], "b": drives["load"], "missing": tmp_path / "missing.eds"}
    assert main(["inspect", *(a.format(**paths) for a in argv)]) != 0
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message.format(**paths) in err and "Traceback" not in err, err

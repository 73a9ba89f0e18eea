"""DBC signals as the DBC defines them: scale, offset, sign and unit; extended ids, CAN FD,
multiplexing, big-endian signals, one or two messages. Every DBC is written here and every frame
is encoded by cantools (``Database.encode_message``)."""

from __future__ import annotations

import json
import math

import can
import cantools
import numpy as np
import pytest

from online_backlash.cli import main
from online_backlash.codecs.blockpairing import BlockPipeline, make_pipeline
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.pairing import FramePipeline
from online_backlash.codecs.units import ANGLE_UNITS
from online_backlash.errors import InvalidParameterError
from online_backlash.simulation.rig import simulate_rig

T0 = 1_700_000_000.0


def dbc(*messages: str) -> cantools.database.can.Database:
    """A database from ``BO_`` blocks (DBC text)."""
    return cantools.database.load_string('VERSION ""\nBU_: RIG\n' + "\n".join(messages), database_format="dbc")


def one_message(motor: str, load: str, frame_id: int = 256, length: int = 8) -> cantools.database.can.Database:
    """Message ``Angles`` with signals ``Motor`` and ``Load`` given as ``start|len@order sign (scale,offset)
    [min|max] "unit"``."""
    return dbc(f"BO_ {frame_id} Angles: {length} RIG\n SG_ Motor : {motor} RIG\n SG_ Load : {load} RIG\n")


def frame(db, name: str, values: dict, t: float = T0, **flags) -> can.Message:
    """A frame of message ``name`` holding physical ``values``, encoded by cantools."""
    message = db.get_message_by_name(name)
    data = db.encode_message(name, values)
    return can.Message(
        timestamp=t,
        arbitration_id=message.frame_id,
        is_extended_id=message.is_extended_frame,
        is_fd=message.is_fd,
        data=data,
        **flags,
    )


def decode_all(decoder: DbcDecoder, frames: list[can.Message], **options) -> list:
    pipe = FramePipeline(decoder, **options)
    out = [s for s in map(pipe.feed, frames) if s is not None]
    pipe.flush()
    return out


# -- the unit decides -------------------------------------------------------------------------
@pytest.mark.parametrize("unit", ["deg", "°", "Degree", "DEG", "rad", "Rad", "rev", "turn", "arcmin", "ArcMin"])
def test_an_angle_unit_gives_degrees_from_the_scaled_physical_value(unit):
    db = one_message(
        f'0|32@1- (0.001,2.5) [-2000000|2000000] "{unit}"', f'32|32@1- (0.0005,-1) [-1000000|1000000] "{unit}"'
    )
    deg_per_unit = ANGLE_UNITS[unit.lower()]
    physical = [(3.25, -7.0), (1234.567, 0.5), (-1999.0, 999.9995)]
    frames = [frame(db, "Angles", {"Motor": m, "Load": y}, T0 + i * 1e-3) for i, (m, y) in enumerate(physical)]
    samples = decode_all(DbcDecoder(db, "Motor", "Load"), frames)
    assert [s.motor_deg for s in samples] == pytest.approx([m * deg_per_unit for m, _ in physical], rel=1e-12, abs=1e-9)
    assert [s.load_deg for s in samples] == pytest.approx([y * deg_per_unit for _, y in physical], rel=1e-12, abs=1e-9)


def test_the_issue_signal_reads_its_play_not_zero():
    """``SG_ ShaftPos : 8|24@1+ (0.01,0) [0|167772.15] "deg"``: multi-turn degrees, not single-turn counts."""
    db = dbc(
        'BO_ 300 Shaft: 4 RIG\n SG_ ShaftPos : 8|24@1+ (0.01,0) [0|167772.15] "deg" RIG\n'
        ' SG_ Seq : 0|8@1+ (1,0) [0|255] "" RIG\n'
    )
    angles = [100.0, 100.25, 120000.5, 167772.15, 0.0]
    frames = [frame(db, "Shaft", {"ShaftPos": a, "Seq": 0}, T0 + i) for i, a in enumerate(angles)]
    samples = decode_all(DbcDecoder(db, "ShaftPos", "ShaftPos", counter_signal=None, checksum_signal=None), frames)
    assert [s.load_deg for s in samples] == pytest.approx(angles, abs=1e-9)  # no wrap at 167772.16: it is not a count


@pytest.mark.parametrize("unit", ["counts", "cnt", "INC", "", "-"])
def test_a_count_wraps_at_raw_max_plus_one_and_is_unwrapped(unit):
    db = one_message(f'0|12@1+ (1,0) [0|4095] "{unit}"', f'16|16@1+ (1,0) [0|65535] "{unit}"')
    decoder = DbcDecoder(db, "Motor", "Load")
    assert (decoder.motor.counts_per_rev, decoder.load.counts_per_rev) == (4096, 65536)
    counts = [4094, 4095, 0, 1, 4095]
    frames = [frame(db, "Angles", {"Motor": c, "Load": 10}, T0 + i * 1e-3) for i, c in enumerate(counts)]
    samples = decode_all(decoder, frames)
    assert [s.motor_deg for s in samples] == pytest.approx([c * 360 / 4096 for c in (4094, 4095, 4096, 4097, 4095)])
    assert DbcDecoder(db, "Motor", "Load", motor_cpr=5000).motor.counts_per_rev == 5000  # --motor-cpr wins


def test_a_signed_count_wraps_over_its_signed_range_and_an_empty_range_means_the_whole_field():
    db = one_message('0|12@1- (1,0) [-2048|2047] "counts"', '16|10@1+ (1,0) [0|0] ""')
    decoder = DbcDecoder(db, "Motor", "Load")
    assert (decoder.motor.counts_per_rev, decoder.load.counts_per_rev) == (4096, 1024)
    counts = [2046, 2047, -2048, -2047, 2047]
    frames = [frame(db, "Angles", {"Motor": c, "Load": 1023}, T0 + i * 1e-3) for i, c in enumerate(counts)]
    assert [s.motor_deg for s in decode_all(decoder, frames)] == pytest.approx(
        [c * 360 / 4096 for c in (2046, 2047, 2048, 2049, 2047)]
    )


@pytest.mark.parametrize(
    "unit, scale, message",
    [
        ("mm", 1, "unit 'mm'"),
        ("counts/s", 1, "unit 'counts/s'"),
        ("", 0.01, "unit '' with scale 0.01"),
        ("counts", 0.5, "unit 'counts' with scale 0.5"),
    ],
)
def test_a_unit_the_tool_cannot_read_stops_naming_signal_and_unit(unit, scale, message):
    db = one_message(f'0|16@1+ ({scale},0) [0|0] "{unit}"', '16|16@1+ (1,0) [0|65535] "counts"')
    with pytest.raises(InvalidParameterError, match=f"Angles.Motor has {message}.*--units"):
        DbcDecoder(db, "Motor", "Load")


def test_units_overrides_the_dbc_unit():
    db = one_message('0|16@1+ (0.01,0) [0|655.35] "mm"', '16|16@1+ (0.01,0) [0|655.35] "mm"')
    f = frame(db, "Angles", {"Motor": 1.5, "Load": 2.0})
    assert decode_all(DbcDecoder(db, "Motor", "Load", units="rad"), [f])[0].motor_deg == pytest.approx(
        math.degrees(1.5)
    )
    counts = DbcDecoder(db, "Motor", "Load", units="counts", motor_cpr=1000, load_cpr=1000)
    assert decode_all(counts, [f])[0].motor_deg == pytest.approx(150 * 0.36)  # raw 150 counts of 1000 per rev


def test_an_angle_wraps_only_when_told():
    db = one_message('0|16@1+ (0.1,0) [0|359.9] "deg"', '16|16@1+ (0.1,0) [0|359.9] "deg"')
    angles = [359.0, 359.9, 0.2, 1.0, 359.5]
    frames = [frame(db, "Angles", {"Motor": a, "Load": a}, T0 + i * 1e-3) for i, a in enumerate(angles)]
    as_given = decode_all(DbcDecoder(db, "Motor", "Load"), frames)
    assert [s.motor_deg for s in as_given] == pytest.approx(angles)
    wrapped = decode_all(DbcDecoder(db, "Motor", "Load", wrap_deg=360), frames)
    assert [s.motor_deg for s in wrapped] == pytest.approx([359.0, 359.9, 360.2, 361.0, 359.5])
    with pytest.raises(InvalidParameterError, match="not a whole number of raw steps"):
        DbcDecoder(db, "Motor", "Load", wrap_deg=360.05)


def test_float_signals_are_read_and_non_finite_values_never_leave_the_decoder():
    db = dbc(
        'BO_ 256 Angles: 8 RIG\n SG_ Motor : 0|32@1- (1,0) [0|0] "rad" RIG\n'
        ' SG_ Load : 32|32@1- (1,0) [0|0] "rad" RIG\n'
        "SIG_VALTYPE_ 256 Motor : 1;\nSIG_VALTYPE_ 256 Load : 1;\n"
    )
    values = [(0.5, -0.25), (float("nan"), 0.0), (1.0, float("inf")), (1.5, 0.75)]
    frames = [frame(db, "Angles", {"Motor": m, "Load": y}, T0 + i * 1e-3) for i, (m, y) in enumerate(values)]
    pipe = make_pipeline(DbcDecoder(db, "Motor", "Load"))
    assert isinstance(pipe, FramePipeline)  # float signals: the per-frame path
    chunk = pipe.feed_frames(frames)
    np.testing.assert_allclose(chunk.motor_deg, np.degrees([0.5, 1.5]))
    np.testing.assert_allclose(chunk.load_deg, np.degrees([-0.25, 0.75]))
    assert (pipe.counters.samples, pipe.counters.corrupt) == (2, 2)


# -- frame kinds ------------------------------------------------------------------------------
def test_extended_29_bit_ids():
    db = dbc(
        'BO_ 2566844926 Ext: 8 RIG\n SG_ Motor : 0|32@1- (0.001,0) [-2000|2000] "deg" RIG\n'
        ' SG_ Load : 32|32@1- (0.001,0) [-2000|2000] "deg" RIG\n'
    )
    message = db.get_message_by_name("Ext")
    assert message.is_extended_frame and message.frame_id > 0x7FF
    good = frame(db, "Ext", {"Motor": 12.5, "Load": -3.25})
    standard = can.Message(
        timestamp=T0, arbitration_id=message.frame_id & 0x7FF, data=good.data
    )  # another frame: not ours
    pipe = FramePipeline(DbcDecoder(db, "Motor", "Load"))
    assert pipe.feed(standard) is None and pipe.counters.skipped == 1
    sample = pipe.feed(good)
    assert (sample.motor_deg, sample.load_deg) == pytest.approx((12.5, -3.25))


def test_can_fd_frames_take_the_per_frame_path():
    db = dbc(
        'BO_ 400 Fd: 64 RIG\n SG_ Motor : 0|32@1- (0.001,0) [-2000|2000] "deg" RIG\n'
        ' SG_ Load : 400|32@1- (0.001,0) [-2000|2000] "deg" RIG\n SG_ Counter : 504|4@1+ (1,0) [0|15] "" RIG\n'
        'BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN",'
        + '"reserved",'
        * 12
        + '"StandardCAN_FD","ExtendedCAN_FD";\n'
        'BA_DEF_DEF_ "VFrameFormat" "StandardCAN";\nBA_ "VFrameFormat" BO_ 400 14;\n'
    )
    assert db.get_message_by_name("Fd").is_fd
    decoder = DbcDecoder(db, "Motor", "Load")
    frames = [
        frame(db, "Fd", {"Motor": 0.1 * i, "Load": -0.2 * i, "Counter": i % 16}, T0 + i * 1e-3) for i in range(40)
    ]
    assert all(f.is_fd and len(f.data) == 64 for f in frames)
    pipe = make_pipeline(decoder)
    assert isinstance(pipe, FramePipeline)
    chunk = pipe.feed_frames(frames)
    np.testing.assert_allclose(chunk.motor_deg, 0.1 * np.arange(40), atol=1e-9)
    np.testing.assert_allclose(chunk.load_deg, -0.2 * np.arange(40), atol=1e-9)
    assert pipe.counters.as_dict()["samples"] == 40 and pipe.counters.gaps == 0


def test_multiplexed_message_reads_the_frames_that_carry_the_signals():
    db = dbc(
        'BO_ 500 Mux: 8 RIG\n SG_ Page M : 0|8@1+ (1,0) [0|255] "" RIG\n'
        ' SG_ Motor m1 : 8|24@1- (0.01,0) [-80000|80000] "deg" RIG\n'
        ' SG_ Load m1 : 32|24@1- (0.01,0) [-80000|80000] "deg" RIG\n'
        ' SG_ Temp m2 : 8|16@1+ (0.1,0) [0|6553.5] "degC" RIG\n'
    )
    frames = []
    for i in range(10):
        frames.append(frame(db, "Mux", {"Page": 1, "Motor": 10.0 + i, "Load": -1.0 * i}, T0 + i * 2e-3))
        frames.append(frame(db, "Mux", {"Page": 2, "Temp": 40.0}, T0 + i * 2e-3 + 1e-3))
    pipe = make_pipeline(DbcDecoder(db, "Motor", "Load"))
    assert isinstance(pipe, FramePipeline)
    chunk = pipe.feed_frames(frames)
    np.testing.assert_allclose(chunk.motor_deg, 10.0 + np.arange(10), atol=1e-9)
    np.testing.assert_allclose(chunk.load_deg, -np.arange(10.0), atol=1e-9)
    assert (pipe.counters.samples, pipe.counters.skipped) == (10, 10)
    with pytest.raises(InvalidParameterError, match="never in the same frame"):
        DbcDecoder(db, "Motor", "Temp", units="deg")


def test_big_endian_signed_signals_on_both_paths():
    db = dbc(
        "BO_ 600 Angles: 8 RIG\n"
        ' SG_ Motor : 7|24@0- (0.01,-5) [-83891.08|83881.07] "deg" RIG\n'
        ' SG_ Load : 31|20@0- (0.000244140625,0) [-128|127.999755859375] "rev" RIG\n'
        ' SG_ Counter : 59|4@0+ (1,0) [0|15] "" RIG\n'
    )
    rng = np.random.default_rng(5)
    motor = np.round(rng.uniform(-80000, 80000, 300), 2)
    load_rev = np.round(rng.uniform(-100, 100, 300) * 4096) / 4096
    frames = [
        frame(db, "Angles", {"Motor": m, "Load": y, "Counter": i % 16}, T0 + i * 1e-3)
        for i, (m, y) in enumerate(zip(motor, load_rev))
    ]
    decoder = DbcDecoder(db, "Motor", "Load")
    per_frame = decode_all(decoder, frames)
    np.testing.assert_allclose([s.motor_deg for s in per_frame], motor, atol=1e-6)
    np.testing.assert_allclose([s.load_deg for s in per_frame], load_rev * 360, atol=1e-9)
    blocks = make_pipeline(decoder)
    assert isinstance(blocks, BlockPipeline)
    assert [s for i in range(0, 300, 64) for s in blocks.feed_frames(frames[i : i + 64]).samples()] == per_frame


def test_two_signals_from_two_messages_pair_by_counter_on_both_paths():
    db = dbc(
        'BO_ 700 MotorMsg: 8 RIG\n SG_ Pos : 0|32@1- (0.0001,0) [-200000|200000] "rev" RIG\n'
        ' SG_ Counter : 32|8@1+ (1,0) [0|255] "" RIG\n'
        'BO_ 701 LoadMsg: 8 RIG\n SG_ Pos : 0|32@1- (0.001,0) [-2000000|2000000] "deg" RIG\n'
        ' SG_ Counter : 32|8@1+ (1,0) [0|255] "" RIG\n'
    )
    frames = []
    for i in range(500):
        frames.append(frame(db, "MotorMsg", {"Pos": 0.001 * i, "Counter": i % 256}, T0 + i * 1e-3))
        frames.append(frame(db, "LoadMsg", {"Pos": 0.5 * i, "Counter": i % 256}, T0 + i * 1e-3 + 5e-5))
    del frames[301]  # a lost load frame: its motor frame is an orphan
    decoder = DbcDecoder(db, "MotorMsg.Pos", "LoadMsg.Pos")
    assert decoder.paired
    per_frame = decode_all(decoder, frames)
    assert len(per_frame) == 499
    np.testing.assert_allclose([s.motor_deg for s in per_frame[:150]], 0.36 * np.arange(150), atol=1e-9)
    np.testing.assert_allclose([s.load_deg for s in per_frame[:150]], 0.5 * np.arange(150), atol=1e-9)
    blocks = make_pipeline(decoder)
    assert isinstance(blocks, BlockPipeline)
    assert [
        s for i in range(0, len(frames), 100) for s in blocks.feed_frames(frames[i : i + 100]).samples()
    ] == per_frame
    blocks.flush()
    assert blocks.counters.unpaired == 1


def test_the_shipped_rig_dbc_is_still_counts():
    decoder = DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count")
    assert decoder.motor.is_count and decoder.load.is_count
    assert (decoder.motor.counts_per_rev, decoder.load.counts_per_rev) == (2**14, 2**17)


# -- end to end -------------------------------------------------------------------------------
MINE_DBC = """VERSION ""
BU_: RIG
BO_ 291 Drive: 8 RIG
 SG_ MotorPos : 0|32@1- (0.001,0) [-2147483.648|2147483.647] "deg" RIG
 SG_ ShaftPos : 32|24@1+ (0.01,0) [0|167772.15] "deg" RIG
"""


@pytest.fixture(scope="module")
def drive_log(tmp_path_factory):
    """A simulated 30:1 rig with 0.5 deg of play, as frames of ``MINE_DBC`` encoded by cantools."""
    rec = simulate_rig(duration_s=40.0, ratio=30.0, play_deg=0.5, seed=7)
    db = cantools.database.load_string(MINE_DBC, database_format="dbc")
    load = rec.load_deg + 1000.0  # the unsigned load signal reads 0 .. 167772.15 deg
    assert load.min() > 0 and np.abs(rec.motor_deg).max() < 2e6
    path = tmp_path_factory.mktemp("drive") / "log.blf"
    with can.Logger(path) as writer:
        for t, m, y in zip((rec.time_s + T0).tolist(), np.round(rec.motor_deg, 3).tolist(), np.round(load, 2).tolist()):
            writer.on_message_received(frame(db, "Drive", {"MotorPos": m, "ShaftPos": y}, t))
    return path


def estimate(capsys, log, dbc_text, *options):
    dbc_path = log.with_name("mine.dbc")
    dbc_path.write_text(dbc_text)
    signals = ["--motor-signal", "Drive.MotorPos", "--load-signal", "Drive.ShaftPos"]
    code = main(["estimate", str(log), "--dbc", str(dbc_path), *signals, "--ratio", "30", "--json", *options])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else err)


def test_estimate_on_a_log_with_scaled_degree_signals(drive_log, capsys):
    code, out = estimate(capsys, drive_log, MINE_DBC)
    assert code == 0
    assert out["backlash_deg"] == pytest.approx(0.5, rel=0.02)


def test_estimate_stops_on_a_unit_it_cannot_read_and_units_overrides_it(drive_log, capsys):
    in_mm = MINE_DBC.replace('"deg"', '"mm"')
    code, err = estimate(capsys, drive_log, in_mm)
    assert code != 0 and "Drive.MotorPos has unit 'mm'" in err and "Traceback" not in err
    code, out = estimate(capsys, drive_log, in_mm, "--units", "deg")
    assert code == 0 and out["backlash_deg"] == pytest.approx(0.5, rel=0.02)


def test_estimate_wrap_deg_unwraps_a_single_turn_angle(drive_log, capsys):
    code, out = estimate(
        capsys, drive_log, MINE_DBC, "--wrap-deg", "360"
    )  # the same motion, read modulo 360 deg and unwrapped
    assert code == 0 and out["backlash_deg"] == pytest.approx(0.5, rel=0.02)
    code, err = estimate(capsys, drive_log, MINE_DBC, "--wrap-deg", "360.005")
    assert code != 0 and "not a whole number of raw steps" in err

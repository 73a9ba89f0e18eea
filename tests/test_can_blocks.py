"""The block paths (CAN frames as arrays with compiled pairing; CSV timestamps in blocks) equal the
per-frame paths, rule by rule, over generated damaged inputs."""

from __future__ import annotations

import can
import cantools
import numpy as np
import pytest
from crccheck.crc import Crc8SaeJ1850
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from online_backlash.codecs.blockdecode import crc8, crc8_table, signal_values, words
from online_backlash.codecs.blockpairing import BlockPipeline, make_pipeline
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.gaps import GapDetector
from online_backlash.codecs.options import CanDecoding, FrameRules
from online_backlash.codecs.pairing import FramePipeline
from online_backlash.replay import canlog, open_log
from online_backlash.replay.canlog import CanLog
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames
from online_backlash.stream import chunked

SPLIT = ("MotorAngle.Count", "LoadAngle.Count")
ONE = ("RigAngles.Motor", "RigAngles.Load")
T0 = 1_700_000_000.0

TEST_DBC = """VERSION ""
BU_: A
BO_ 16 Mixed: 8 A
 SG_ LeU : 3|13@1+ (1,0) [0|0] "" A
 SG_ LeS : 18|11@1- (1,0) [0|0] "" A
 SG_ BeU : 39|12@0+ (1,0) [0|0] "" A
 SG_ BeS : 43|17@0- (1,0) [0|0] "" A
 SG_ Top : 58|1@1+ (1,0) [0|0] "" A
BO_ 17 Short: 5 A
 SG_ BeOdd : 13|19@0+ (1,0) [0|0] "" A
 SG_ LeOdd : 33|7@1- (1,0) [0|0] "" A
"""


def test_the_crc_table_comes_from_crccheck_and_gives_its_crc():
    table = crc8_table()
    assert table[0] == 0 and len(set(table.tolist())) == 256  # a CRC table is a permutation with 0 -> 0
    rng = np.random.default_rng(1)
    for width in range(0, 9):
        rows = rng.integers(0, 256, size=(300, width), dtype=np.uint8)
        assert crc8(rows).tolist() == [Crc8SaeJ1850.calc(bytes(r)) for r in rows]


def test_signal_values_equal_cantools_decode_both_byte_orders_and_signs():
    db = cantools.database.load_string(TEST_DBC, database_format="dbc")
    rng = np.random.default_rng(2)
    for message in db.messages:
        rows = rng.integers(0, 256, size=(500, message.length), dtype=np.uint8)
        le, be = words(rows)
        for signal in message.signals:
            expected = [message.decode_simple(bytes(r), False, False)[signal.name] for r in rows]
            assert signal_values(le, be, signal).tolist() == expected, signal.name


def damaged_frames(signals, counter_signal="Counter"):
    """A simulated run with every kind of trouble: corrupt, foreign, orphans, lost frames, silence, time going back."""
    rec = simulate_rig(duration_s=0.6, rate_hz=1000.0, seed=3)
    dec = DbcDecoder(RIG_DBC, *signals, counter_signal=counter_signal)
    frames = list(rig_can_frames(rec, dec, T0, skew_s=1e-4))
    ours = frames[0].arbitration_id
    n = len(frames)  # 1200 frames in two messages, 600 in one
    for f in frames[97::97]:
        f.data[1] ^= 0x10  # bad checksum
    for f in frames[131::131]:
        f.data = f.data[:-1]  # wrong length
        f.dlc = len(f.data)
    del frames[n // 3 : n // 3 + 5]  # lost frames: a counter jump (and an orphan in two messages)
    del frames[n // 2]
    frames[n // 2 + 100 : n // 2 + 102] = [
        frames[n // 2 + 100],
        frames[n // 2 + 100],
        frames[n // 2 + 101],
    ]  # a repeated frame
    for f in frames[3 * n // 4 :]:
        f.timestamp += 0.05  # a silence
    for f in frames[n // 4 : n // 4 + 2]:
        f.timestamp = T0 - 1.0  # time goes backwards
    extra = [
        can.Message(timestamp=T0, arbitration_id=0x3AB, data=b"\xde\xad"),  # other traffic
        can.Message(timestamp=T0, arbitration_id=ours, is_error_frame=True),
        can.Message(timestamp=T0, arbitration_id=ours, is_remote_frame=True, dlc=len(frames[0].data)),
        can.Message(timestamp=T0, arbitration_id=ours, is_extended_id=True, data=frames[0].data),
    ]
    for k, i in enumerate(range(50, len(frames), 150)):
        msg = extra[k % len(extra)]
        frames.insert(
            i,
            can.Message(
                timestamp=frames[i].timestamp,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_error_frame=msg.is_error_frame,
                is_remote_frame=msg.is_remote_frame,
                dlc=msg.dlc,
                data=msg.data,
            ),
        )
    return frames


@pytest.mark.parametrize(
    "signals, options",
    [
        (SPLIT, {}),
        (SPLIT, {"counter_signal": None, "max_skew_s": 2e-4}),  # paired by time
        (ONE, {}),
        (ONE, {"motor_cpr": 16000, "period_s": 1e-3}),  # counts >= 16000 are out of range, so corrupt
    ],
    ids=["by-counter", "by-time", "one-message", "out-of-range"],
)
@pytest.mark.parametrize("block_frames", [7, canlog.BLOCK_FRAMES])
def test_block_path_equals_the_per_frame_path(tmp_path, monkeypatch, signals, options, block_frames):
    monkeypatch.setattr(canlog, "BLOCK_FRAMES", block_frames)
    frames = damaged_frames(signals, options.get("counter_signal", "Counter"))
    path = tmp_path / "run.blf"
    with can.Logger(path) as writer:
        for f in frames:
            writer.on_message_received(f)
    decoder_options = {k: options[k] for k in ("motor_cpr", "counter_signal") if k in options}
    pipe = FramePipeline(
        DbcDecoder(RIG_DBC, *signals, **decoder_options), options.get("period_s"), options.get("max_skew_s", 1e-3)
    )
    expected = [s for s in map(pipe.feed, can.LogReader(path)) if s is not None]
    pipe.flush()

    log = open_log(path, dbc=RIG_DBC, motor_signal=signals[0], load_signal=signals[1], **options)
    assert log.block_path
    assert list(log) == expected  # time, angles, seq and after_gap, exactly
    c, e = log.counters, pipe.counters
    assert c.as_dict() == e.as_dict() and list(c.gap_log) == list(e.gap_log)
    assert (log.pipeline.skew_mean_s, log.pipeline.skew_max_s) == (pipe.skew_mean_s, pipe.skew_max_s)
    assert c.corrupt > 0 and c.skipped > 0 and c.gaps > 0 and (c.unpaired > 0 or signals == ONE)

    want = list(chunked(expected, 100))
    got = list(
        open_log(path, dbc=RIG_DBC, motor_signal=signals[0], load_signal=signals[1], **options).iter_chunks(
            max_samples=100
        )
    )
    assert [len(g) for g in got] == [len(w) for w in want]
    for g, w in zip(got, want):
        for field in ("time_s", "motor_deg", "load_deg", "after_gap"):
            assert np.array_equal(getattr(g, field), getattr(w, field)), field
        assert np.isnan(g.torque_Nm).all()
        assert [q if q >= 0 else None for q in g.seq.tolist()] == [
            s.seq for s in w.samples()
        ]  # the rolling counters ride along


def test_realtime_and_strict_take_the_per_frame_path(tmp_path):
    log = CanLog(tmp_path / "x.blf", CanDecoding(RIG_DBC, *SPLIT))
    assert log.block_path
    assert not CanLog(tmp_path / "x.blf", CanDecoding(RIG_DBC, *SPLIT), realtime=True).block_path
    assert not CanLog(tmp_path / "x.blf", CanDecoding(RIG_DBC, *SPLIT), frames=FrameRules(strict=True)).block_path


# -- every rule, over generated damage ----------------------------------------------------------
#: Angles with a DBC scale, offset, sign and unit (big- and little-endian), with a counter and a checksum.
SCALED_DBC = cantools.database.load_string(
    """VERSION ""
BU_: RIG
BO_ 1 Scaled: 8 RIG
 SG_ Motor : 7|24@0- (0.01,-5) [-83891.08|83881.07] "deg" RIG
 SG_ Load : 24|20@1- (0.000244140625,0.5) [-127.5|128.5] "rev" RIG
 SG_ Counter : 44|4@1+ (1,0) [0|15] "" RIG
 SG_ Checksum : 56|8@1+ (1,0) [0|255] "" RIG
""",
    database_format="dbc",
)
SCALED = ("Scaled.Motor", "Scaled.Load")
#: name -> (dbc, signals, decoder options, pipeline options)
CONFIGS = {
    "by-counter": (RIG_DBC, SPLIT, {}, {}),
    "by-counter-no-checksum": (
        RIG_DBC,
        SPLIT,
        {"checksum_signal": None},
        {},
    ),  # flips reach counters and counts: jumps, unwrapping
    "by-time": (RIG_DBC, SPLIT, {"counter_signal": None}, {"max_skew_s": 2e-4}),
    "one-message-no-checksum": (
        RIG_DBC,
        ONE,
        {"checksum_signal": None, "motor_cpr": 16000},
        {"period_s": 1e-3},
    ),  # out-of-range counts
    "scaled-multi-turn": (SCALED_DBC, SCALED, {"checksum_signal": None}, {}),  # flips reach scaled, signed values
    "scaled-wrapping": (SCALED_DBC, SCALED, {"wrap_deg": 360.0}, {}),  # angles unwrapped at 360 deg
}
DAMAGE = (
    "flip",
    "cut",
    "pad",
    "drop",
    "repeat",
    "swap",
    "foreign",
    "extended",
    "error",
    "remote",
    "silence",
    "back",
    "nan",
)


def clean_frames(dbc, signals, decoder_options):
    rec = simulate_rig(duration_s=0.15, rate_hz=1000.0, seed=4)
    return list(rig_can_frames(rec, DbcDecoder(dbc, *signals, **decoder_options), T0, skew_s=1e-4))


CLEAN = {name: clean_frames(dbc, signals, dec) for name, (dbc, signals, dec, _) in CONFIGS.items()}


def copy(f):
    return can.Message(
        timestamp=f.timestamp, arbitration_id=f.arbitration_id, is_extended_id=f.is_extended_id, data=bytearray(f.data)
    )


def damage(frames, ops):
    """A copy of ``frames`` with each ``(index, kind, value)`` applied in turn."""
    out = [copy(f) for f in frames]
    for index, kind, value in ops:
        i = index % len(out)
        f = out[i]
        if kind == "flip":
            f.data[value % len(f.data)] ^= 1 << (value % 8)
        elif kind in ("cut", "pad"):
            f.data = f.data[:-1] if kind == "cut" else f.data + b"\0"  # wrong length
            f.dlc = len(f.data)
        elif kind == "drop" and len(out) > 1:
            del out[i]  # a lost frame: a counter jump, an orphan
        elif kind == "repeat":
            out.insert(i, copy(f))
        elif kind == "swap" and i + 1 < len(out):
            out[i], out[i + 1] = out[i + 1], f
        elif kind == "foreign":
            f.arbitration_id = 0x3AB  # not ours
        elif kind == "extended":
            f.is_extended_id = True  # our id, other format: not ours
        elif kind in ("error", "remote"):
            setattr(f, f"is_{kind}_frame", True)
        elif kind == "silence":
            for later in out[i:]:
                later.timestamp += 1e-4 * (
                    1 + value
                )  # 1.1 to 26.6 periods: around the gap rule's 3, maybe a whole counter wrap
        elif kind == "back":
            f.timestamp -= 1.0  # time goes backwards
        elif kind == "nan":
            f.timestamp = float("nan")  # non-finite
    return out


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(sorted(CONFIGS)),
    ops=st.lists(st.tuples(st.integers(0, 10_000), st.sampled_from(DAMAGE), st.integers(0, 255)), max_size=25),
    block=st.integers(1, 400),
)
def test_every_frame_rule_is_the_same_on_both_paths(name, ops, block):
    """Checksum, length, foreign and special frames, pairing and orphans, counter jumps, unwrapping,
    time order, non-finite times and gaps: the block path equals the per-frame path, whatever the damage
    and wherever the blocks are cut."""
    dbc, signals, decoder_options, options = CONFIGS[name]
    frames = damage(CLEAN[name], ops)
    decoder = DbcDecoder(dbc, *signals, **decoder_options)
    per_frame = FramePipeline(decoder, **options)
    expected = [s for s in map(per_frame.feed, frames) if s is not None]
    per_frame.flush()
    blocks = make_pipeline(decoder, **options)
    assert isinstance(blocks, BlockPipeline)
    got = [s for i in range(0, len(frames), block) for s in blocks.feed_frames(frames[i : i + block]).samples()]
    blocks.flush()
    assert got == expected
    assert blocks.counters.as_dict() == per_frame.counters.as_dict()
    assert list(blocks.counters.gap_log) == list(per_frame.counters.gap_log)
    np.testing.assert_equal((blocks.skew_mean_s, blocks.skew_max_s), (per_frame.skew_mean_s, per_frame.skew_max_s))
    c = blocks.counters
    assert c.frames == c.skipped + c.corrupt + c.unpaired + blocks.frames_per_sample * c.samples
    assert c.samples > len(CLEAN[name]) // (2 * blocks.frames_per_sample)  # most frames are still good ones


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(
        st.one_of(st.just(1e-3), st.floats(0.0, 0.02), st.sampled_from([0.0, 0.05, 1.0])), min_size=0, max_size=80
    ),
    block=st.integers(1, 30),
    period_s=st.sampled_from([None, 1e-3, 4e-3]),
)
def test_the_gap_rule_on_blocks_of_times_is_the_sample_by_sample_rule(steps, block, period_s):
    times = np.cumsum([0.0, *steps])
    one = GapDetector(period_s=period_s)
    expected = [one.check(t) for t in times.tolist()]
    blocks = GapDetector(period_s=period_s)
    flags, gaps = [], []
    for i in range(0, times.size, block):
        f, g = blocks.check_times(times[i : i + block])
        flags += f.tolist()
        gaps += g
    assert flags == [g is not None for g in expected]
    assert gaps == [g for g in expected if g is not None]
    assert blocks.period_s == one.period_s

"""Fuzzing the parsers: random bytes, truncations and bit flips.

Only the documented error types escape (FrameError when strict, LogFormatError for a damaged
log file), nothing non-finite is ever yielded, and the counters reconcile.
"""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.pairing import FramePipeline
from online_backlash.codecs.serialframes import AsciiParser, BinaryParser, encode_ascii, encode_binary
from online_backlash.errors import FrameError, LogFormatError
from online_backlash.replay import open_log
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
CPR = {"motor_cpr": 2**14, "load_cpr": 2**17}
SPLIT = {"dbc": RIG_DBC, "motor_signal": "MotorAngle.Count", "load_signal": "LoadAngle.Count"}


def make_parser(fmt, strict=False):
    return AsciiParser(strict=strict) if fmt == "ascii" else BinaryParser(**CPR, strict=strict)


def feed_all(parser, chunks):
    out = []
    for chunk in chunks:
        out += parser.feed(chunk)
    return out


def check_serial(parser, samples):
    c = parser.counters
    assert c.frames == c.samples + c.corrupt and c.samples == len(samples) and c.skipped == 0
    assert all(s.is_finite() for s in samples)
    times = [s.time_s for s in samples]
    assert times == sorted(times)


GOOD = {
    "ascii": b"".join(encode_ascii(i * 1e-3, 0.1 * i, -0.2 * i) for i in range(40)),
    "binary": b"".join(encode_binary(i, i * 1000, 7 * i, -3 * i) for i in range(40)),
}


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
@FUZZ
@given(chunks=st.lists(st.binary(max_size=200), max_size=20))
def test_random_bytes(fmt, chunks):
    parser = make_parser(fmt)
    check_serial(parser, feed_all(parser, chunks))
    strict = make_parser(fmt, strict=True)
    try:
        feed_all(strict, chunks)
    except FrameError:
        pass


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
@FUZZ
@given(data=st.data())
def test_bit_flips_and_truncation_of_a_good_stream(fmt, data):
    stream = bytearray(GOOD[fmt])
    for pos in data.draw(st.lists(st.integers(0, len(stream) * 8 - 1), max_size=6)):
        stream[pos // 8] ^= 1 << (pos % 8)
    stream = bytes(stream[: data.draw(st.integers(0, len(stream)))])
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=5)))
    parser = make_parser(fmt)
    samples = feed_all(parser, [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)])])
    check_serial(parser, samples)


@FUZZ
@given(pos=st.integers(0, len(GOOD["binary"]) * 8 - 1))
def test_one_bit_flip_never_yields_a_sample_that_was_not_sent(pos):
    stream = bytearray(GOOD["binary"])
    stream[pos // 8] ^= 1 << (pos % 8)
    sent = {(s.seq, s.time_s, s.motor_deg, s.load_deg) for s in BinaryParser(**CPR).feed(GOOD["binary"])}
    parser = BinaryParser(**CPR)
    got = parser.feed(bytes(stream))
    assert {(s.seq, s.time_s, s.motor_deg, s.load_deg) for s in got} <= sent
    assert (parser.counters.corrupt >= 1 or parser.pending_bytes > 0) and len(got) >= 38  # the flip is never silent


# -- CAN -----------------------------------------------------------------------------------
frames_st = st.builds(
    can.Message,
    timestamp=st.floats(allow_nan=True, allow_infinity=True),
    arbitration_id=st.sampled_from([0x100, 0x101, 0x102, 0x7FF, 0]),
    is_extended_id=st.booleans(),
    is_error_frame=st.booleans(),
    data=st.binary(max_size=8),
    check=st.just(False),
)


@pytest.mark.parametrize("signals", [("RigAngles.Motor", "RigAngles.Load"), ("MotorAngle.Count", "LoadAngle.Count")])
@FUZZ
@given(msgs=st.lists(frames_st, max_size=40))
def test_random_frames(signals, msgs):
    pipe = FramePipeline(DbcDecoder(RIG_DBC, *signals))
    samples = [s for s in map(pipe.feed, msgs) if s is not None]
    pipe.flush()
    c = pipe.counters
    assert c.frames == len(msgs) == c.skipped + c.corrupt + c.unpaired + pipe.frames_per_sample * c.samples
    assert c.samples == len(samples) and all(s.is_finite() for s in samples)
    strict = FramePipeline(DbcDecoder(RIG_DBC, *signals), strict=True)
    try:
        for m in msgs:
            strict.feed(m)
    except FrameError:
        pass


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    rec = simulate_rig(duration_s=0.1, rate_hz=1000.0, seed=1)
    frames = list(
        rig_can_frames(rec, DbcDecoder(RIG_DBC, SPLIT["motor_signal"], SPLIT["load_signal"]), 1_700_000_000.0)
    )
    out = {}
    for suffix in (".asc", ".blf", ".log", ".trc"):
        path = tmp_path_factory.mktemp("logs") / f"good{suffix}"
        with can.Logger(path) as w:
            for f in frames:
                w.on_message_received(f)
        out[suffix] = path.read_bytes()
    return out


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log", ".trc"])
@FUZZ
@given(data=st.data())
def test_damaged_can_logs(logs, tmp_path_factory, suffix, data):
    raw = bytearray(logs[suffix])
    for pos in data.draw(st.lists(st.integers(0, len(raw) * 8 - 1), max_size=8)):
        raw[pos // 8] ^= 1 << (pos % 8)
    raw = bytes(raw[: data.draw(st.integers(0, len(raw)))])
    if data.draw(st.booleans()):
        raw += data.draw(st.binary(max_size=64))
    path = tmp_path_factory.mktemp("fuzz") / f"damaged{suffix}"
    path.write_bytes(raw)
    try:
        list(open_log(path, **SPLIT))
    except LogFormatError as exc:
        assert exc.path == str(path)
    log = open_log(path, **SPLIT, skip_bad=True)
    samples = list(log)
    c = log.counters
    assert c.frames == c.skipped + c.corrupt + c.unpaired + 2 * c.samples and c.samples == len(samples)
    assert all(math.isfinite(s.time_s) and s.is_finite() for s in samples)

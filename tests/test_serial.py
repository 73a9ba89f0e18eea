"""Serial adapter: both frame formats, resynchronisation, capture, live == replay (loop:// and a pty)."""

from __future__ import annotations

import os
import threading
import tty

import numpy as np
import pytest

from online_backlash import VorosBacklash
from online_backlash.codecs.options import Counts
from online_backlash.codecs.serialframes import AsciiParser, BinaryParser, encode_ascii, encode_binary
from online_backlash.drivers.live import LiveOptions
from online_backlash.drivers.serial import SerialSource
from online_backlash.errors import FrameError, InvalidParameterError, LogFormatError
from online_backlash.replay import open_log
from online_backlash.replay.serialcapture import SerialCapture
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_serial_records
from online_backlash.stream import SampleSource

CPR = {"motor_cpr": 2**14, "load_cpr": 2**17}


@pytest.fixture(scope="module")
def rec():
    return simulate_rig(duration_s=3.0, rate_hz=1000.0, reversal_s=(0.4, 0.8), seed=5)


def parser_for(fmt, **kw):
    return AsciiParser(**kw) if fmt == "ascii" else BinaryParser(**CPR, **kw)


def reconciles(c):
    return c.frames == c.samples + c.corrupt and c.skipped == 0


# -- parsers -------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_records_split_anywhere_give_the_same_samples(rec, fmt):
    stream = b"".join(rig_serial_records(rec, fmt, **CPR))
    whole = parser_for(fmt).feed(stream)
    bits = parser_for(fmt)
    cuts = np.random.default_rng(0).integers(0, len(stream), 500)
    pieces = [stream[a:b] for a, b in zip(np.r_[0, np.sort(cuts)], np.r_[np.sort(cuts), len(stream)])]
    split = [s for p in pieces for s in bits.feed(p)]
    assert split == whole and len(whole) == rec.time_s.size
    assert (
        np.array_equal([s.load_deg for s in whole], rec.load_deg)
        if fmt == "binary"
        else np.allclose([s.load_deg for s in whole], rec.load_deg, atol=1e-9)
    )
    assert reconciles(bits.counters) and bits.counters.corrupt == 0


def test_ascii_bad_lines_are_corrupt_and_the_parser_resyncs():
    data = (
        encode_ascii(0.000, 1.0, 2.0)
        + b"garbage\n"
        + b"0.001,1.1\n"  # two fields
        + b"0.002,nan,2.2\r\n"  # non-finite
        + b"\xff\xfe,1,2\n"  # not text
        + b"x" * 1000  # no newline at all: one corrupt frame, discarded to the next newline
        + b"tail of it\n"
        + encode_ascii(0.003, 1.3, 2.3)
        + encode_ascii(0.002, 1.4, 2.4)  # time goes backwards
        + b"\n\n"
        + encode_ascii(0.004, 1.5, 2.5)
    )
    p = AsciiParser()
    samples = p.feed(data)
    assert [s.motor_deg for s in samples] == [1.0, 1.3, 1.5]
    c = p.counters
    assert (c.frames, c.samples, c.corrupt) == (9, 3, 6) and reconciles(c)
    with pytest.raises(FrameError, match="3 comma-separated fields"):
        AsciiParser(strict=True).feed(b"1,2\n")


def test_binary_crc_errors_garbage_and_lost_frames():
    frames = [encode_binary(i, i * 1000, 10 * i, 20 * i) for i in range(40)]
    flipped = bytearray(frames[5])
    flipped[4] ^= 0x04  # a bit flip inside the frame: the CRC catches it
    frames[5] = bytes(flipped)
    frames[9] = b"\x13\x37garbage" + frames[9][3:]  # a damaged frame, resynchronised at its zero byte
    del frames[20:25]  # five frames lost
    p = BinaryParser(**CPR)
    samples = p.feed(b"\x01\x02\x03" + b"".join(frames))  # starts mid-frame
    c = p.counters
    assert (c.samples, c.corrupt) == (32, 3) and reconciles(c)  # frame 0 is joined to the leading bytes
    assert [s.seq for s in samples if s.after_gap] == [6, 10, 25]
    assert [g.missing for g in c.gap_log] == [1, 1, 5]
    assert samples[-1].motor_deg == pytest.approx(39 * 10 * 360 / 2**14)


def test_binary_counts_unwrap_through_the_32_bit_rollover():
    p = BinaryParser(motor_cpr=1000, load_cpr=1000)
    counts = [2**31 - 2, 2**31 - 1, 2**31, 2**31 + 5]  # encode_binary wraps them to int32
    out = p.feed(b"".join(encode_binary(i, i * 1000, c, -c) for i, c in enumerate(counts)))
    steps = np.diff([s.motor_deg for s in out]) / 0.36
    assert np.allclose(steps, [1, 1, 5]) and np.allclose(np.diff([s.load_deg for s in out]) / 0.36, [-1, -1, -5])


def test_binary_needs_counts_per_revolution():
    with pytest.raises(InvalidParameterError, match="motor_cpr"):
        BinaryParser()
    with pytest.raises(InvalidParameterError, match="serial_format"):
        open_log("x.serial")


# -- live ----------------------------------------------------------------------------------
def run_live(source, payload, write, chunk=997):
    """Write ``payload`` from a thread while polling ``source`` until every byte has arrived."""
    writer = threading.Thread(target=lambda: [write(payload[i : i + chunk]) for i in range(0, len(payload), chunk)])
    writer.start()
    samples = []
    while source.bytes_read < len(payload):
        got = source.poll()
        samples += got.samples() if got is not None else []
    writer.join()
    source.close()
    return samples


def faulty_stream(rec, fmt):
    records = list(rig_serial_records(rec, fmt, **CPR))
    records[300] = records[300][:5] + b"\xaa" + records[300][6:]  # damaged
    records.insert(700, b"\x00\x17 line noise \x00\n")  # garbage
    del records[1200:1230]  # lost
    return b"".join(records)


def fit(samples, ratio):
    u = np.array([s.motor_deg for s in samples]) / ratio
    return VorosBacklash().fit(u, np.array([s.load_deg for s in samples]))


@pytest.mark.parametrize(
    ("fmt", "port"), [("ascii", "loop://"), ("binary", "loop://"), ("binary", "pty"), ("ascii", "pty")]
)
def test_live_estimates_equal_the_replayed_capture_bit_for_bit(tmp_path, rec, fmt, port):
    payload = faulty_stream(rec, fmt)
    if port == "pty":
        master, slave = os.openpty()
        tty.setraw(slave)
        source = SerialSource(os.ttyname(slave), 115200, fmt, counts=Counts(**CPR), live=LiveOptions(tmp_path))
        live = run_live(source, payload, lambda b: os.write(master, b))
        os.close(master)
        os.close(slave)
    else:
        source = SerialSource("loop://", 115200, fmt, counts=Counts(**CPR), live=LiveOptions(tmp_path))
        live = run_live(source, payload, source.port.write)
    c = source.counters
    assert isinstance(source, SampleSource)
    assert c.corrupt >= 2 and c.gaps >= 1 and reconciles(c)
    (capture,) = source.raw_log.files
    assert capture.read_bytes() == payload  # verbatim, garbage included

    log = open_log(capture, serial_format=fmt, **CPR)
    replayed = list(log)
    assert isinstance(log, SampleSource)
    assert replayed == live
    assert log.counters.as_dict() == c.as_dict()
    fitted = ("m_left_", "c_left_", "m_right_", "c_right_", "backlash_", "residual_rms_")
    est_live, est_replay = fit(live, rec.ratio), fit(replayed, rec.ratio)
    assert [getattr(est_live, a) for a in fitted] == [getattr(est_replay, a) for a in fitted]
    assert est_live.backlash_ == pytest.approx(0.5, abs=0.05)


def test_a_capture_cut_inside_a_frame(tmp_path):
    source = SerialSource("loop://", 115200, "binary", counts=Counts(**CPR), live=LiveOptions(tmp_path))
    payload = b"".join(encode_binary(i, i * 1000, i, i) for i in range(10))[:-7]
    run_live(source, payload, source.port.write)
    c = source.counters
    assert (c.samples, c.corrupt) == (9, 1) and reconciles(c)  # live: the tail is one corrupt frame
    capture = source.raw_log.files[0]
    with pytest.raises(LogFormatError, match=rf"{capture.name}:9: capture ends inside a frame"):
        list(open_log(capture, serial_format="binary", **CPR))
    log = SerialCapture(tmp_path, "binary", counts=Counts(**CPR), skip_bad=True)  # a whole --raw-log directory
    assert len(list(log)) == 9 and log.counters.as_dict() == c.as_dict()


def test_capture_rotates_and_the_files_concatenate_to_the_bytes_received(tmp_path, rec):
    from online_backlash.drivers.rawlog import RawByteLog

    payload = b"".join(rig_serial_records(rec, "ascii"))
    raw = RawByteLog(tmp_path, max_bytes=10_000)
    for i in range(0, len(payload), 333):
        raw.write(payload[i : i + 333])
    raw.close()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert len(names) > 5 and names == [p.name for p in raw.files]
    assert b"".join((tmp_path / n).read_bytes() for n in names) == payload
    assert len(list(SerialCapture(tmp_path, serial_format="ascii"))) == rec.time_s.size


def test_a_silent_port_times_out_and_a_duration_ends_the_stream():
    from online_backlash.errors import SourceTimeoutError

    with SerialSource("loop://", 115200, "ascii", live=LiveOptions(timeout_s=0.2)) as source:
        with pytest.raises(SourceTimeoutError, match=r"nothing received for 0\.2 s on serial port"):
            next(iter(source))
    with SerialSource("loop://", 115200, "ascii", live=LiveOptions(duration_s=0.2)) as source:
        assert list(source) == []
        assert source.bytes_read == 0

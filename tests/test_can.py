"""CAN adapter: DBC decoding, checks, pairing, unwrapping, gaps, raw log, live == replay."""

from __future__ import annotations

import itertools
import threading

import can
import numpy as np
import pytest
from can.interfaces.virtual import VirtualBus
from live_run import LIMIT_S

from online_backlash import VorosBacklash
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder, FrameEncoder, resolve_signal
from online_backlash.codecs.options import CanDecoding, FrameRules
from online_backlash.codecs.pairing import FramePipeline
from online_backlash.codecs.unwrap import Unwrapper
from online_backlash.drivers.can import CanSource
from online_backlash.drivers.live import LiveOptions
from online_backlash.drivers.rawlog import RawCanLog
from online_backlash.errors import FrameError, InvalidParameterError, SourceError
from online_backlash.replay import open_log
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames
from online_backlash.stream import SampleSource

SPLIT = ("MotorAngle.Count", "LoadAngle.Count")
ONE = ("RigAngles.Motor", "RigAngles.Load")
T0 = 1_700_000_000.0  # epoch seconds, as a real bus timestamps frames


def reconciles(counters, frames_per_sample):
    return (
        counters.frames
        == counters.skipped + counters.corrupt + counters.unpaired + frames_per_sample * counters.samples
    )


@pytest.fixture(scope="module")
def rec():
    return simulate_rig(duration_s=3.0, rate_hz=1000.0, speed_deg_s=60.0, reversal_s=(0.4, 0.8), seed=3)


# -- DBC ---------------------------------------------------------------------------------
def test_counts_per_revolution_come_from_the_dbc_or_the_caller():
    dec = DbcDecoder(RIG_DBC, *SPLIT)
    assert (dec.motor.counts_per_rev, dec.load.counts_per_rev) == (2**14, 2**17)
    assert dec.paired and dec.counter_modulus == 16
    assert DbcDecoder(RIG_DBC, *ONE, motor_cpr=10000).motor.counts_per_rev == 10000
    assert not DbcDecoder(RIG_DBC, *ONE).paired


def test_signal_names_are_checked():
    db = DbcDecoder(RIG_DBC, *ONE).db
    with pytest.raises(InvalidParameterError, match="ambiguous"):
        resolve_signal(db, "Count")
    with pytest.raises(InvalidParameterError, match="not in the DBC"):
        resolve_signal(db, "MotorAngle.Nope")
    assert resolve_signal(db, "Motor").message.name == "RigAngles"


def test_a_file_that_is_not_a_dbc_is_an_invalid_parameter(tmp_path):
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a dbc\n")
    with pytest.raises(InvalidParameterError, match=r"bad\.dbc"):
        DbcDecoder(bad, *ONE)


# -- unwrapping -----------------------------------------------------------------------------
def test_unwrap_follows_turns_both_ways():
    true = np.concatenate([np.arange(0, 5 * 2**14, 3000), np.arange(5 * 2**14, -3 * 2**14, -5000)])
    u = Unwrapper(2**14)
    got = np.array([u(int(c) % 2**14) for c in true])
    assert np.array_equal(got - got[0], true - true[0])


@pytest.mark.parametrize("signals", [ONE, SPLIT])
def test_decoded_angles_are_the_encoder_angles_unwrapped(rec, signals):
    dec = DbcDecoder(RIG_DBC, *signals)
    pipe = FramePipeline(dec)
    samples = [s for s in map(pipe.feed, rig_can_frames(rec, dec, T0)) if s is not None]
    assert len(samples) == rec.time_s.size
    motor = np.array([s.motor_deg for s in samples])
    load = np.array([s.load_deg for s in samples])
    # multi-turn: equal to the simulated angle up to whole turns fixed at the first sample
    for got, want in ((motor, rec.motor_deg), (load, rec.load_deg)):
        offset = got - want
        assert np.ptp(offset) < 1e-9
        assert abs(offset[0] / 360 - round(offset[0] / 360)) < 1e-9
    assert np.ptp(rec.motor_deg) > 2 * 360  # the motor did wrap several times
    assert pipe.counters.gaps == 0 and reconciles(pipe.counters, pipe.frames_per_sample)


# -- bad frames ----------------------------------------------------------------------------
def frames_for(dec, n, start=0):
    enc = FrameEncoder(dec)
    return [f for i in range(start, start + n) for f in enc.frames(T0 + i * 1e-3, 100 + i, 200 + i, i)]


def test_bad_checksum_wrong_length_and_foreign_ids_are_counted_not_yielded():
    dec = DbcDecoder(RIG_DBC, *ONE)
    frames = frames_for(dec, 10)
    bad_crc = frames[3].data
    bad_crc[0] ^= 0x01
    frames[5].data = frames[5].data[:7]
    frames[5].dlc = 7
    foreign = can.Message(timestamp=T0, arbitration_id=0x7FF, data=b"\x00" * 8)
    error = can.Message(timestamp=T0, arbitration_id=0x100, is_error_frame=True)
    pipe = FramePipeline(dec)
    out = [pipe.feed(f) for f in [*frames[:6], foreign, error, *frames[6:]]]
    assert sum(s is not None for s in out) == 8
    c = pipe.counters
    assert (c.frames, c.samples, c.corrupt, c.skipped) == (12, 8, 2, 2)
    assert c.gaps == 2  # the two corrupt frames leave holes in the counter
    assert reconciles(c, 1)
    with pytest.raises(FrameError, match="checksum"):
        FramePipeline(dec, strict=True).feed(frames[3])


def test_counter_jump_is_a_gap_with_time_and_length_and_flags_the_next_sample():
    dec = DbcDecoder(RIG_DBC, *ONE)
    frames = frames_for(dec, 20)
    del frames[10:13]  # counters 10, 11, 12 lost
    pipe = FramePipeline(dec)
    samples = [s for s in map(pipe.feed, frames) if s is not None]
    assert [s.after_gap for s in samples].count(True) == 1
    flagged = next(s for s in samples if s.after_gap)
    assert flagged.seq == 13
    (gap,) = pipe.counters.gap_log
    assert gap.missing == 3 and gap.time_s == flagged.time_s and gap.duration_s == pytest.approx(4e-3, abs=1e-6)


def test_long_silence_is_a_gap_even_when_the_counter_wraps_round():
    dec = DbcDecoder(RIG_DBC, *ONE)
    frames = frames_for(dec, 40)
    del frames[20:36]  # 16 lost: the 4-bit counter looks continuous, the time does not
    pipe = FramePipeline(dec)
    samples = [s for s in map(pipe.feed, frames) if s is not None]
    assert pipe.counters.gaps == 1 and pipe.counters.gap_log[0].missing == 16
    assert sum(s.after_gap for s in samples) == 1


def test_pairing_by_counter_counts_orphans_and_reports_skew():
    dec = DbcDecoder(RIG_DBC, *SPLIT)
    frames = frames_for(dec, 30)
    for f in frames[1::2]:
        f.timestamp += 2e-4  # load frame 0.2 ms after the motor frame
    frames[2 * 7 + 1].data[0] ^= 0xFF  # load of sample 7 corrupt: motor 7 is left unpaired
    frames[2 * 20], frames[2 * 20 + 1] = frames[2 * 20 + 1], frames[2 * 20]  # load before motor
    del frames[2 * 12]  # motor of sample 12 lost: load 12 is left unpaired
    pipe = FramePipeline(dec)
    samples = [s for s in map(pipe.feed, frames) if s is not None]
    pipe.flush()
    c = pipe.counters
    assert len(samples) == c.samples == 28 and c.corrupt == 1 and c.unpaired == 2
    assert reconciles(c, 2)
    assert pipe.skew_max_s == pytest.approx(2e-4, abs=1e-6) and pipe.skew_mean_s == pytest.approx(2e-4, abs=1e-6)
    assert [s.seq for s in samples if s.after_gap] == [8, 13]


def test_pairing_by_time_without_counters():
    dec = DbcDecoder(RIG_DBC, *SPLIT, counter_signal=None)
    frames = frames_for(dec, 10)
    del frames[5]  # load of sample 2
    pipe = FramePipeline(dec, max_skew_s=1e-4)
    samples = [s for s in map(pipe.feed, frames) if s is not None]
    pipe.flush()
    assert len(samples) == 9 and pipe.counters.unpaired == 1 and reconciles(pipe.counters, 2)
    assert all(s.seq is None for s in samples)


def test_time_going_backwards_is_corrupt():
    dec = DbcDecoder(RIG_DBC, *ONE)
    frames = frames_for(dec, 5)
    frames[3].timestamp = T0 - 1
    pipe = FramePipeline(dec)
    assert sum(pipe.feed(f) is not None for f in frames) == 4 and pipe.counters.corrupt == 1


# -- raw log -------------------------------------------------------------------------------
def test_raw_log_rotates_and_sorted_names_give_the_frames_in_order(tmp_path, rec):
    dec = DbcDecoder(RIG_DBC, *SPLIT)
    sent = list(itertools.islice(rig_can_frames(rec, dec, T0), 3000))
    raw = RawCanLog(tmp_path, "asc", max_bytes=20_000)
    for f in sent:
        raw.on_message_received(f)
    raw.stop()
    files = sorted(p.name for p in tmp_path.iterdir())
    assert len(files) > 3 and files == [p.name for p in raw.files]
    assert all(n.startswith("can-") and n.endswith(".asc") and "active" not in n for n in files)
    got = [m for name in files for m in can.LogReader(tmp_path / name)]
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(m.arbitration_id, bytes(m.data)) for m in sent]


# -- live == replay ------------------------------------------------------------------------
def play_live(frames, raw_dir, signals, raw_format, channel):
    """Send ``frames`` on a virtual bus to a CanSource; return its samples and counters."""
    tx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    rx = can.Bus(interface="virtual", channel=channel)
    with CanSource(rx, CanDecoding(RIG_DBC, *signals), live=LiveOptions(raw_dir, raw_format)) as source:
        for f in frames:
            tx.send(f)
        tx.shutdown()
        source.stop()  # the frames the notifier has not read yet are still waiting on the bus: the stop takes them
        samples = list(source)
    return samples, source


class HeldBus(VirtualBus):
    """A virtual bus whose notifier thread never gets a frame (it waits as on a quiet bus): every frame sent
    is still waiting when the source stops."""

    def __init__(self, channel: str) -> None:
        super().__init__(channel=channel)
        self.quiet = threading.Event()  # never set

    def _recv_internal(self, timeout):
        if threading.current_thread() is threading.main_thread():
            return super()._recv_internal(timeout)
        self.quiet.wait(timeout)
        return None, False


def test_the_frames_still_waiting_on_the_bus_at_a_stop_are_logged_and_learned(tmp_path, rec):
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, *SPLIT), T0))
    tx = can.Bus(interface="virtual", channel="held", preserve_timestamps=True)
    with CanSource(HeldBus("held"), CanDecoding(RIG_DBC, *SPLIT), live=LiveOptions(tmp_path)) as source:
        for f in frames:
            tx.send(f)
        tx.shutdown()
        source.request_stop()  # Ctrl-C right after the last frame
        samples = list(source)
    assert source.counters.frames == source.raw_log.frames == len(frames)
    assert len(samples) == source.counters.samples == rec.time_s.size
    assert [m.arbitration_id for m in can.LogReader(source.raw_log.files[0])] == [f.arbitration_id for f in frames]


def learn(samples, ratio):
    u = np.array([s.motor_deg for s in samples]) / ratio
    return VorosBacklash().fit(u, np.array([s.load_deg for s in samples]))


@pytest.mark.parametrize(("signals", "raw_format"), [(SPLIT, "blf"), (ONE, "asc"), (SPLIT, "log")])
def test_live_estimates_equal_the_replayed_raw_log_bit_for_bit(tmp_path, rec, signals, raw_format):
    dec = DbcDecoder(RIG_DBC, *signals)
    frames = list(rig_can_frames(rec, dec, T0, skew_s=1e-4))
    # faults on the bus: foreign traffic, a corrupt frame, a lost stretch
    frames.insert(100, can.Message(timestamp=frames[99].timestamp, arbitration_id=0x555, data=b"\x01\x02"))
    frames[500].data[1] ^= 0x10
    del frames[1500:1540]
    live, source = play_live(frames, tmp_path, signals, raw_format, f"live-{raw_format}")
    assert isinstance(source, SampleSource)
    c = source.counters
    assert c.frames == len(frames) == source.raw_log.frames
    assert c.skipped == 1 and c.corrupt == 1 and c.gaps >= 1
    assert reconciles(c, source.pipeline.frames_per_sample)

    log = open_log(source.raw_log.files[0], dbc=RIG_DBC, motor_signal=signals[0], load_signal=signals[1])
    replayed = list(log)
    assert isinstance(log, SampleSource)
    assert log.counters.as_dict() == c.as_dict()
    assert [(s.motor_deg, s.load_deg, s.seq, s.after_gap) for s in replayed] == [
        (s.motor_deg, s.load_deg, s.seq, s.after_gap) for s in live
    ]
    assert np.allclose([s.time_s for s in replayed], [s.time_s for s in live], rtol=0, atol=1e-3)

    est_live, est_replay = learn(live, rec.ratio), learn(replayed, rec.ratio)
    fitted = ("m_left_", "c_left_", "m_right_", "c_right_", "backlash_", "residual_rms_")
    assert [getattr(est_live, a) for a in fitted] == [getattr(est_replay, a) for a in fitted]
    assert est_live.backlash_ == pytest.approx(0.5, abs=0.05)


def test_a_failing_bus_ends_the_stream_with_a_source_error(tmp_path):
    rx = can.Bus(interface="virtual", channel="failing")

    def broken(timeout):
        raise can.CanOperationError("controller went bus-off")

    with CanSource(rx, CanDecoding(RIG_DBC, *ONE), live=LiveOptions(tmp_path)) as source:
        rx._recv_internal = broken
        with pytest.raises(SourceError, match="bus-off"):
            next(iter(source))


def test_strict_decoding_raises_the_frame_error_in_the_consumer(tmp_path):
    dec = DbcDecoder(RIG_DBC, *ONE)
    (frame,) = FrameEncoder(dec).frames(T0, 1, 2, 0)
    frame.data[0] ^= 1
    tx = can.Bus(interface="virtual", channel="strict", preserve_timestamps=True)
    rx = can.Bus(interface="virtual", channel="strict")
    with CanSource(
        rx, CanDecoding(RIG_DBC, *ONE), frames=FrameRules(strict=True), live=LiveOptions(tmp_path)
    ) as source:
        tx.send(frame)
        tx.shutdown()
        with pytest.raises(FrameError, match="checksum"):
            next(iter(source))
    assert source.raw_log.frames == 1  # logged before it was decoded


def test_a_silent_bus_times_out_and_a_duration_ends_the_stream(tmp_path):
    from online_backlash.errors import SourceTimeoutError

    with CanSource(
        can.Bus(interface="virtual", channel="silent"), CanDecoding(RIG_DBC, *ONE), live=LiveOptions(timeout_s=0.2)
    ) as source:
        with pytest.raises(SourceTimeoutError, match=r"nothing received for 0\.2 s on CAN"):
            next(iter(source))
    with CanSource(
        can.Bus(interface="virtual", channel="quiet"), CanDecoding(RIG_DBC, *ONE), live=LiveOptions(duration_s=0.2)
    ) as source:
        assert list(source.iter_chunks()) == []
        assert source.counters.frames == 0


def test_ctrl_c_ends_a_quiet_bus_even_when_its_handler_outlives_the_wait():
    """A Ctrl-C handler that asks the source to stop and returns normally, run while the source waits
    for a frame and finishing after that wait's deadline: CPython's ``SimpleQueue.get(timeout=...)``
    then waits for ever unless something is put on the queue, which ``request_stop`` does. Run in a
    child process so that the old behaviour shows as a timeout (a hang guard), not a hung suite."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent(
        """
        import signal, time
        import can
        from online_backlash.codecs.dbc import RIG_DBC
        from online_backlash.codecs.options import CanDecoding
        from online_backlash.drivers.can import _POLL_S, CanSource

        signals = CanDecoding(RIG_DBC, "RigAngles.Motor", "RigAngles.Load")
        source = CanSource(can.Bus(interface="virtual", channel="ctrl-c"), signals)

        def on_interrupt(*_):
            time.sleep(3 * _POLL_S)  # the handler outlives the wait it interrupted
            source.request_stop()

        signal.signal(signal.SIGALRM, on_interrupt)
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        assert list(source.iter_chunks()) == []
        source.close()
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=LIMIT_S)
    assert done.returncode == 0, done.stderr

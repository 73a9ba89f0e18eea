"""The sample stream helpers and the synthetic rig used by demo, tests and benchmarks."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from online_backlash.drivers.can import CanSource
from online_backlash.drivers.live import LiveSource
from online_backlash.drivers.serial import SerialSource
from online_backlash.errors import InvalidParameterError
from online_backlash.replay import LOG_READERS, CsvLog, open_log, read_csv_arrays
from online_backlash.replay.canlog import CanLog
from online_backlash.replay.serialcapture import SerialCapture
from online_backlash.simulation.rig import quantise, simulate_rig
from online_backlash.stream import (
    Gap,
    Sample,
    SampleSource,
    StreamCounters,
    chunked,
    concat_chunks,
    rechunk,
    refer_to_load,
)


def test_sample_is_frozen_and_checks_finiteness():
    s = Sample(0.0, 1.0, 2.0)
    with pytest.raises(AttributeError):
        s.time_s = 1.0  # type: ignore[misc]
    assert s.is_finite()
    assert not Sample(0.0, math.nan, 2.0).is_finite()
    assert not Sample(0.0, 1.0, 2.0, torque_Nm=math.inf).is_finite()


def test_chunked_keeps_every_sample_in_order():
    samples = [Sample(i * 1e-3, float(i), -float(i), None, i, i == 5) for i in range(23)]
    chunks = list(chunked(samples, size=10))
    assert [len(c) for c in chunks] == [10, 10, 3]
    np.testing.assert_array_equal(np.concatenate([c.motor_deg for c in chunks]), np.arange(23.0))
    assert np.flatnonzero(np.concatenate([c.after_gap for c in chunks])).tolist() == [5]
    assert np.isnan(chunks[0].torque_Nm).all()
    with pytest.raises(InvalidParameterError):
        list(chunked(samples, size=0))


def test_the_sequence_numbers_ride_along_in_the_chunks():
    samples = [Sample(i * 1e-3, float(i), 0.0, None, None if i == 2 else i) for i in range(5)]
    (chunk,) = chunked(samples)
    assert chunk.seq.tolist() == [0, 1, -1, 3, 4] and list(chunk.samples()) == samples
    (plain,) = chunked([Sample(0.0, 1.0, 2.0)])
    assert plain.seq is None and list(plain.samples()) == [Sample(0.0, 1.0, 2.0)]


def test_rechunk_gives_blocks_of_exactly_max_samples_in_order():
    samples = [Sample(i * 1e-3, float(i), -float(i), None, i, i % 7 == 0) for i in range(50)]
    pieces = list(chunked(samples, size=3))
    for max_samples, lengths in ((8, [8] * 6 + [2]), (1, [1] * 50), (100, [50]), (None, [3] * 16 + [2])):
        got = list(rechunk(iter(pieces), max_samples))
        assert [len(c) for c in got] == lengths
        assert [s for c in got for s in c.samples()] == samples
    joined = concat_chunks(pieces)
    assert joined.seq.tolist() == list(range(50)) and list(joined.samples()) == samples
    with pytest.raises(InvalidParameterError):
        list(rechunk(iter(pieces), 0))


SOURCES = [CsvLog, CanLog, SerialCapture, LiveSource, CanSource, SerialSource]


@pytest.mark.parametrize(
    "cls", SOURCES + sorted({r for r in LOG_READERS.values() if isinstance(r, type)} - set(SOURCES), key=str)
)
def test_every_source_keeps_the_one_contract(cls):
    """One ``iter_chunks(max_samples=None)`` signature; iteration and the context manager come from SampleSource."""
    assert issubclass(cls, SampleSource)
    signature = inspect.signature(cls.iter_chunks)
    assert list(signature.parameters) == ["self", "max_samples"] and signature.parameters["max_samples"].default is None
    for name in ("__iter__", "__enter__", "__exit__"):
        assert getattr(cls, name) is getattr(SampleSource, name), f"{cls.__name__} writes its own {name}"


def test_open_log_gives_a_sample_source_whose_chunks_and_samples_agree(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text("time,motor,load\n" + "".join(f"{i * 0.001:.3f},{i},{-i}\n" for i in range(20)))
    log = open_log(path, block_rows=6)
    assert isinstance(log, SampleSource)
    with log:
        assert [len(c) for c in log.iter_chunks()] == [6, 6, 6, 2]
        assert [len(c) for c in log.iter_chunks(max_samples=8)] == [8, 8, 4]
        assert [s.motor_deg for s in log] == [float(i) for i in range(20)]


def test_counters_report_gaps():
    c = StreamCounters()
    c.report_gap(Gap(1.5, 0.01, 9))
    assert c.gaps == 1 and c.gap_log[0].missing == 9
    assert c.as_dict()["gaps"] == 1


@pytest.mark.parametrize("ratio", [0, math.nan, math.inf])
def test_ratio_must_be_finite_and_nonzero(ratio):
    with pytest.raises(InvalidParameterError, match="ratio"):
        refer_to_load(np.ones(3), ratio)


def test_negative_ratio_reverses_the_referred_angle():
    np.testing.assert_array_equal(refer_to_load(np.array([30.0, -60.0]), -30.0), [-1.0, 2.0])


def test_quantise_is_an_encoder():
    step = 360 / 2**10
    q = quantise(np.array([0.0, step * 0.99, step * 1.01, -step * 0.5]), 10)
    np.testing.assert_allclose(q / step, [0, 0, 1, -1])


def test_rig_recording_round_trips_through_csv_in_counts(tmp_path):
    rec = simulate_rig(duration_s=5.0, seed=4)
    path = tmp_path / "rig.csv.gz"
    rec.write_csv(path, units="counts")
    back = read_csv_arrays(path, units="counts", motor_cpr=2**14, load_cpr=2**17)
    np.testing.assert_allclose(back.motor_deg, rec.motor_deg, atol=1e-9)
    np.testing.assert_allclose(back.load_deg, rec.load_deg, atol=1e-9)
    assert len(back) == 5000


def test_rig_play_follows_the_wear_function_and_the_motion_reverses():
    rec = simulate_rig(duration_s=30.0, play_deg=lambda t: 0.2 + 0.001 * t, seed=1)
    assert rec.play_deg[0] == pytest.approx(0.2) and rec.play_deg[-1] == pytest.approx(0.23, abs=1e-4)
    du = np.diff(rec.u_true_deg)
    assert (du > 0).any() and (du < 0).any()
    # the load never leaves the band between the two flank lines (plus noise and quantisation)
    lost = rec.load_deg - rec.load_deg[0] - (rec.u_true_deg - rec.u_true_deg[0])
    assert np.ptp(lost) < rec.play_deg.max() + 0.05

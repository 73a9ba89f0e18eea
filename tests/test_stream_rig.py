"""The sample stream helpers and the synthetic rig used by demo, tests and benchmarks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from online_backlash.errors import InvalidParameterError
from online_backlash.replay import read_csv_arrays
from online_backlash.rig import quantise, simulate_rig
from online_backlash.stream import Gap, Sample, StreamCounters, chunked, refer_to_load


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

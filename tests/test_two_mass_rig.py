"""The two-mass rig simulator: play, wind-up and the engaged flank follow from its dynamics."""

import numpy as np
import pytest

from online_backlash.errors import InvalidParameterError
from online_backlash.simulation.two_mass_rig import ARCMIN_PER_DEG, simulate_two_mass


def test_engaged_flank_is_flank_offset_plus_windup():
    rec = simulate_two_mass(
        duration_s=10, play_deg=0.4, left_fraction=0.3, stiffness_nm_per_arcmin=0.1, torque_noise_nm=0.0, seed=1
    )
    y_true = rec.load_deg - rec.load_deg[0]  # quantised; offsets removed below via the rest of the identity
    tau = rec.torque_true_Nm
    k_deg = rec.stiffness_nm_per_arcmin * ARCMIN_PER_DEG
    right, left = tau > 0.05, tau < -0.05
    assert right.sum() > 1000 and left.sum() > 1000
    # y = u - c_right - tau/k on the right flank, y = u + c_left - tau/k on the left (contact damping aside)
    offset_right = np.median((rec.u_true_deg - tau / k_deg - y_true)[right])
    offset_left = np.median((rec.u_true_deg - tau / k_deg - y_true)[left])
    assert offset_right - offset_left == pytest.approx(0.4, abs=0.01)


def test_external_torque_above_the_motion_torque_stops_the_torque_reversing():
    low = simulate_two_mass(duration_s=10, external_torque_nm=0.1, seed=2)
    high = simulate_two_mass(duration_s=10, external_torque_nm=1.0, seed=2)
    assert low.reversals_of_torque >= 8
    assert high.reversals_of_torque == 0
    assert (high.torque_true_Nm > 0).all()


def test_chunk_and_csv_carry_the_measured_torque(tmp_path):
    rec = simulate_two_mass(duration_s=2, seed=3)
    chunk = rec.to_chunk()
    np.testing.assert_array_equal(chunk.torque_Nm, rec.torque_Nm)
    path = tmp_path / "two_mass.csv"
    rec.write_csv(path)
    header, first = path.read_text().splitlines()[:2]
    assert header == "time,motor,load,torque"
    assert float(first.split(",")[3]) == pytest.approx(rec.torque_Nm[0], abs=1e-6)


def _lost_motion_rising(overrun_nm: float) -> tuple[np.ndarray, np.ndarray]:
    """The lost motion ``u - y`` (deg) of a train with two gaps while the motor rises, and the motor angle there;
    the load torque pushes the load up, ``overrun_nm`` at the bottom of the stroke, nothing at the top."""
    rec = simulate_two_mass(
        duration_s=10.0, play_deg=0.4, second_gap_deg=0.15, stiffness_nm_per_arcmin=1.0, viscous_nms_per_rad=0.05,
        external_torque_nm=lambda t: -overrun_nm * (1.0 - np.sin(np.pi * t)) / 2.0, seed=5,
    )  # fmt: skip
    falling, rising = np.gradient(rec.u_true_deg) < 0, np.gradient(rec.u_true_deg) > 0
    lost = rec.u_true_deg - (rec.load_deg - rec.load_deg[0] + rec.u_true_deg[0])
    return lost[rising] - np.median(lost[falling]), rec.u_true_deg[rising]


def test_a_second_gap_is_crossed_in_two_steps_where_a_load_torque_overruns():
    """Two gaps in series, 0.25 and 0.15 deg: without a load torque the load crosses both at every reversal
    (lost motion 0.4 deg rising, wind-up aside); a torque pushing the load up holds the second gap crossed the
    other way over the lower part of the rising stroke, so the load follows there 0.15 deg short."""
    plain, at = _lost_motion_rising(0.0)
    assert np.median(plain[at > -20.0]) == pytest.approx(0.4, abs=0.02)
    held, at = _lost_motion_rising(0.3)
    assert np.median(held[(at > -20.0) & (at < 10.0)]) == pytest.approx(0.25, abs=0.02)
    assert np.median(held[at > 25.0]) == pytest.approx(0.4, abs=0.02)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"play_deg": -0.1}, {"stiffness_nm_per_arcmin": 0.0}, {"motion": "square"}, {"stiffness_nm_per_arcmin": 1e4},
        {"second_gap_deg": 0.5}, {"second_gap_deg": -0.1}, {"second_gap_deg": 0.1, "intermediate_inertia_kgm2": 0.0},
        {"second_gap_deg": 0.1, "stiffness_segments": ((0.02, 0.05, 0.12), (0.08, 0.25))},
    ],
)  # fmt: skip
def test_bad_parameters_are_refused(kwargs):
    with pytest.raises(InvalidParameterError):
        simulate_two_mass(duration_s=1, **kwargs)

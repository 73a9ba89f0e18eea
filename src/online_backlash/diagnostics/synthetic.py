"""Known effects added to a simulated rig recording, for tests and benchmarks of the loop.

Each function takes a :class:`~online_backlash.rig.RigRecording` (from
:func:`~online_backlash.rig.simulate_rig`, slopes 1) and returns ``(time_s, motor_deg,
load_deg, torque_Nm)`` with one effect acting on the true load angle ``x`` (rebuilt from the
recording's true input and dead band, eq. 1-3); the recording's own noise and quantisation
error ride along and the load angle is quantised again by the same encoder. Angles in
degrees, time in seconds, torque in N m (NaN: no torque column).
"""

from __future__ import annotations

import numpy as np

from ..model import simulate_backlash_varying
from ..rig import RigRecording, quantise
from ._causal import velocity_deg_s

Record = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _true_load(rec: RigRecording) -> np.ndarray:
    return simulate_backlash_varying(rec.u_true_deg, 1.0, rec.c_left_deg, 1.0, rec.c_right_deg)


def _with(rec: RigRecording, disturbance_deg: np.ndarray, load_bits: int, torque_Nm: np.ndarray | None = None) -> Record:
    n = rec.time_s.size
    load = quantise(rec.load_deg + disturbance_deg, load_bits)
    return rec.time_s, rec.motor_deg, load, np.full(n, np.nan) if torque_Nm is None else torque_Nm


def clean(rec: RigRecording, load_bits: int = 17) -> Record:
    """The recording as it is."""
    return _with(rec, np.zeros_like(rec.load_deg), load_bits)


def transmission_error(
    rec: RigRecording, load_order: int = 2, load_amp_deg: float = 0.02, motor_order: int = 1, motor_amp_deg: float = 0.01, load_bits: int = 17
) -> Record:
    """Add ``A sin(n x + 0.7) + B sin(k motor_angle + 1.9)`` to the load angle (``x`` the true load angle)."""
    x = _true_load(rec)
    te = load_amp_deg * np.sin(np.radians(load_order * x) + 0.7)
    te += motor_amp_deg * np.sin(np.radians(motor_order * rec.u_true_deg * rec.ratio) + 1.9)
    return _with(rec, te, load_bits)


def delay(rec: RigRecording, lag_samples: int = 4, load_bits: int = 17) -> Record:
    """The load encoder sampled ``lag_samples`` later than the motor encoder: ``x(t - lag)``."""
    x = _true_load(rec)
    late = np.concatenate((np.full(lag_samples, x[0]), x[: x.size - lag_samples]))
    return _with(rec, late - x, load_bits)


def compliance(
    rec: RigRecording,
    compliance_deg_per_Nm: float = 0.04,
    coulomb_Nm: float = 1.0,
    viscous_Nm_s_per_deg: float = 0.05,
    torque_noise_Nm: float = 0.02,
    load_bits: int = 17,
    seed: int = 0,
) -> Record:
    """A load torque (Coulomb + viscous in the speed) twists the shaft by ``compliance * torque``; the torque is logged with noise."""
    rng = np.random.default_rng(seed)
    v = velocity_deg_s(rec.u_true_deg, rec.time_s, 10)
    torque = coulomb_Nm * np.tanh(v / 2.0) + viscous_Nm_s_per_deg * v
    return _with(rec, -compliance_deg_per_Nm * torque, load_bits, torque + rng.normal(0.0, torque_noise_Nm, torque.size))


def drift(rec: RigRecording, amp_deg: float = 0.2, tau_s: float = 60.0, load_bits: int = 17) -> Record:
    """An encoder zero that warms up: ``amp (1 - exp(-t / tau))`` added to the load angle."""
    t = rec.time_s - rec.time_s[0]
    return _with(rec, amp_deg * (1.0 - np.exp(-t / tau_s)), load_bits)


def speed_dependent_lag(rec: RigRecording, lag_s_at_ref: float = 0.0015, ref_speed_deg_s: float = 30.0, load_bits: int = 17) -> Record:
    """Outside the library: a lag that grows with the square of the speed, ``x(t - d(|v|))``."""
    x = _true_load(rec)
    v = velocity_deg_s(rec.u_true_deg, rec.time_s, 10)
    lag = lag_s_at_ref * (v / ref_speed_deg_s) ** 2
    return _with(rec, np.interp(rec.time_s - lag, rec.time_s, x) - x, load_bits)


#: effect name -> function, for the benchmark
INJECTORS = {
    "clean": clean,
    "transmission_error": transmission_error,
    "delay": delay,
    "compliance": compliance,
    "drift": drift,
    "outside_library": speed_dependent_lag,
}

"""Known effects added to a simulated rig recording, for tests and benchmarks of the loop.

Each function takes a :class:`~online_backlash.simulation.rig.RigRecording` (from
:func:`~online_backlash.simulation.rig.simulate_rig`, slopes 1) and returns ``(time_s, motor_deg,
load_deg, torque_Nm)`` with one effect acting on the true load angle ``x`` (rebuilt from the
recording's true input and dead band, eq. 1-3); the recording's own noise and quantisation
error ride along and the load angle is quantised again by the same encoder. Angles in
degrees, time in seconds, torque in N m (NaN: no torque column).

The ``two_mass_*`` functions start instead from the two-mass rig
(:func:`~online_backlash.simulation.two_mass_rig.simulate_two_mass`), a simulator the estimator does not
assume (see the section below).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..diagnostics._causal import velocity_deg_s
from ..model import simulate_backlash_varying
from .rig import RigRecording, quantise
from .two_mass_rig import TwoMassRecording, simulate_two_mass

Record = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _true_load(rec: RigRecording) -> np.ndarray:
    return simulate_backlash_varying(rec.u_true_deg, 1.0, rec.c_left_deg, 1.0, rec.c_right_deg)


def _with(
    rec: RigRecording, disturbance_deg: np.ndarray, load_bits: int, torque_Nm: np.ndarray | None = None
) -> Record:
    n = rec.time_s.size
    load = quantise(rec.load_deg + disturbance_deg, load_bits)
    return rec.time_s, rec.motor_deg, load, np.full(n, np.nan) if torque_Nm is None else torque_Nm


def clean(rec: RigRecording, load_bits: int = 17) -> Record:
    """The recording as it is."""
    return _with(rec, np.zeros_like(rec.load_deg), load_bits)


def transmission_error(
    rec: RigRecording,
    load_order: int = 2,
    load_amp_deg: float = 0.02,
    motor_order: int = 1,
    motor_amp_deg: float = 0.01,
    load_bits: int = 17,
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
    """A load torque (Coulomb + viscous in the speed) twists the shaft by ``compliance * torque``; the torque is
    logged with noise."""
    rng = np.random.default_rng(seed)
    v = velocity_deg_s(rec.u_true_deg, rec.time_s, 10)
    torque = coulomb_Nm * np.tanh(v / 2.0) + viscous_Nm_s_per_deg * v
    return _with(
        rec, -compliance_deg_per_Nm * torque, load_bits, torque + rng.normal(0.0, torque_noise_Nm, torque.size)
    )


def drift(rec: RigRecording, amp_deg: float = 0.2, tau_s: float = 60.0, load_bits: int = 17) -> Record:
    """An encoder zero that warms up: ``amp (1 - exp(-t / tau))`` added to the load angle."""
    t = rec.time_s - rec.time_s[0]
    return _with(rec, amp_deg * (1.0 - np.exp(-t / tau_s)), load_bits)


def speed_dependent_lag(
    rec: RigRecording, lag_s_at_ref: float = 0.0015, ref_speed_deg_s: float = 30.0, load_bits: int = 17
) -> Record:
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


# --- logs from a simulator the estimator does not assume ------------------------------------
#
# The injectors above add an effect to a load angle written by the estimator's own model
# (eq. 1-3). The ones below start from the two-mass rig (:mod:`online_backlash.simulation.two_mass_rig`):
# play, wind-up and the flank in contact follow from its equations of motion, the load coasts
# through the dead band, and the load encoder is quantised once, after the effect is added.

#: the two-mass rig of the benchmark: 30:1, 1 kHz, continuous rotation with reversals, 0.05 N m
#: of Coulomb friction on the output, a 17-bit load encoder
TWO_MASS_RIG: dict[str, Any] = {"motion": "rig", "coulomb_nm": 0.05, "play_deg": 0.5}
#: a stiff gear (10 N m/arcmin): its wind-up stays below the load encoder's step
STIFF_NM_PER_ARCMIN = 10.0
#: a compliant gear (0.1 N m/arcmin): the twist under the torque the motion needs is tens of steps
COMPLIANT_NM_PER_ARCMIN = 0.1


def _two_mass(seed: int, duration_s: float, stiffness_nm_per_arcmin: float) -> TwoMassRecording:
    """The rig with a load angle kept unquantised (30 bits) until the effect is added."""
    return simulate_two_mass(
        duration_s=duration_s,
        seed=seed,
        stiffness_nm_per_arcmin=stiffness_nm_per_arcmin,
        substeps=40,
        load_bits=30,
        **TWO_MASS_RIG,
    )


def _record(rec: TwoMassRecording, disturbance_deg: np.ndarray, torque: bool = False, load_bits: int = 17) -> Record:
    q = rec.torque_Nm if torque else np.full(rec.time_s.size, np.nan)
    return rec.time_s, rec.motor_deg, quantise(rec.load_deg + disturbance_deg, load_bits), q


def two_mass_clean(seed: int = 0, duration_s: float = 180.0) -> Record:
    """The stiff two-mass rig as it is (no torque column)."""
    rec = _two_mass(seed, duration_s, STIFF_NM_PER_ARCMIN)
    return _record(rec, np.zeros_like(rec.load_deg))


def two_mass_transmission_error(
    seed: int = 0, duration_s: float = 180.0, load_amp_deg: float = 0.02, motor_amp_deg: float = 0.01
) -> Record:
    """The stiff rig with ``A sin(2 y + 0.7) + B sin(motor angle + 1.9)`` added to the load angle ``y``."""
    rec = _two_mass(seed, duration_s, STIFF_NM_PER_ARCMIN)
    te = load_amp_deg * np.sin(np.radians(2.0 * rec.load_deg) + 0.7) + motor_amp_deg * np.sin(
        np.radians(rec.motor_deg) + 1.9
    )
    return _record(rec, te)


def two_mass_delay(seed: int = 0, duration_s: float = 180.0, lag_samples: int = 4) -> Record:
    """The stiff rig with the load encoder read ``lag_samples`` after the motor encoder."""
    rec = _two_mass(seed, duration_s, STIFF_NM_PER_ARCMIN)
    y = rec.load_deg
    late = np.concatenate((np.full(lag_samples, y[0]), y[: y.size - lag_samples]))
    return _record(rec, late - y)


def two_mass_compliance(seed: int = 0, duration_s: float = 180.0) -> Record:
    """The compliant rig (0.1 N m/arcmin): the output twists under the torque its motion needs;
    the transmitted torque is logged (with the sensor's noise of 0.005 N m)."""
    rec = _two_mass(seed, duration_s, COMPLIANT_NM_PER_ARCMIN)
    return _record(rec, np.zeros_like(rec.load_deg), torque=True)


def two_mass_drift(seed: int = 0, duration_s: float = 180.0, amp_deg: float = 0.2, tau_s: float = 60.0) -> Record:
    """The stiff rig with an encoder zero that warms up, ``amp (1 - exp(-t / tau))``."""
    rec = _two_mass(seed, duration_s, STIFF_NM_PER_ARCMIN)
    return _record(rec, amp_deg * (1.0 - np.exp(-(rec.time_s - rec.time_s[0]) / tau_s)))


def two_mass_speed_dependent_lag(
    seed: int = 0, duration_s: float = 180.0, lag_s_at_ref: float = 0.0015, ref_speed_deg_s: float = 30.0
) -> Record:
    """Outside the library, on the stiff rig: a lag that grows with the square of the speed."""
    rec = _two_mass(seed, duration_s, STIFF_NM_PER_ARCMIN)
    v = velocity_deg_s(rec.u_true_deg, rec.time_s, 10)
    lag = lag_s_at_ref * (v / ref_speed_deg_s) ** 2
    return _record(rec, np.interp(rec.time_s - lag, rec.time_s, rec.load_deg) - rec.load_deg)


#: effect name -> function(seed, duration_s), for the benchmark on the two-mass rig
TWO_MASS_INJECTORS = {
    "clean": two_mass_clean,
    "transmission_error": two_mass_transmission_error,
    "delay": two_mass_delay,
    "compliance": two_mass_compliance,
    "drift": two_mass_drift,
    "outside_library": two_mass_speed_dependent_lag,
}


# --- an inertial twist without a torque column -----------------------------------------------
#
# The load follows a flank through a soft shaft: the torque it needs to accelerate, ``J y''``, twists the
# shaft by ``J y'' / k``. The motion is prescribed in closed form, and the twist is computed from its
# analytic acceleration (not from the quantised angles the tool reads, so a tool cannot succeed by
# differentiating them the way the simulator did).

#: the inertial-twist log's default ``J / k``, s^2: a natural frequency of 15.9 Hz (a 0.002 kg m^2 load on
#: 0.0035 N m/arcmin), twists of up to 0.1 deg on the two-tone motion
INERTIA_OVER_STIFFNESS_S2 = 1e-4


def _raised_cosine_ramps(
    t: np.ndarray, starts_s: np.ndarray, speed_steps: np.ndarray, ramp_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Angle (deg) and acceleration (deg/s^2) of a speed that changes by ``speed_steps`` (deg/s), each
    over ``ramp_s`` seconds from ``starts_s``, with the raised-cosine acceleration
    ``(dv / T) (1 - cos(2 pi s / T))``, from rest at angle 0: in closed form (the speed's ramp
    ``S(x) = x - sin(2 pi x) / (2 pi)`` and its integral ``x^2 / 2 + (cos(2 pi x) - 1) / (4 pi^2)``)."""
    angle, acc = np.zeros_like(t), np.zeros_like(t)
    for t0, dv in zip(starts_s, speed_steps):
        x = (t - t0) / ramp_s
        on = (x > 0) & (x < 1)
        acc[on] += dv / ramp_s * (1.0 - np.cos(2.0 * np.pi * x[on]))
        angle[on] += dv * ramp_s * (x[on] ** 2 / 2.0 + (np.cos(2.0 * np.pi * x[on]) - 1.0) / (4.0 * np.pi**2))
        after = x >= 1
        angle[after] += dv * ramp_s * (x[after] - 0.5)
    return angle, acc


def point_to_point_motion(
    duration_s: float,
    rate_hz: float = 1000.0,
    seed: int = 0,
    ramp_s: float = 0.15,
    speed_deg_s: tuple[float, float] = (20.0, 60.0),
    distance_deg: tuple[float, float] = (5.0, 60.0),
    dwell_s: tuple[float, float] = (0.05, 0.5),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time (s), load-side angle (deg) and its acceleration (deg/s^2) of point-to-point moves: each of a
    random length and direction, at a random top speed, reached and left with raised-cosine acceleration
    over ``ramp_s``, then a random dwell at rest (a servo axis indexing)."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(duration_s * rate_hz)) / rate_hz
    starts, steps = [], []
    now = 0.0
    while now < duration_s:
        v = rng.uniform(*speed_deg_s) * rng.choice((-1.0, 1.0))
        cruise = max(rng.uniform(*distance_deg) / abs(v) - ramp_s, 0.0)  # a move of |v| (ramp + cruise) deg
        starts += [now, now + ramp_s + cruise]
        steps += [v, -v]
        now += 2.0 * ramp_s + cruise + rng.uniform(*dwell_s)
    angle, acc = _raised_cosine_ramps(t, np.array(starts), np.array(steps), ramp_s)
    return t, angle, acc


def two_tone_motion(
    duration_s: float,
    rate_hz: float = 1000.0,
    seed: int = 0,
    amplitudes_deg: tuple[float, float] = (30.0, 10.0),
    frequencies_hz: tuple[float, float] = (0.5, 1.3),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time (s), load-side angle (deg) and its acceleration (deg/s^2) of two sines with phases drawn from
    ``seed``. (One sine's acceleration is its angle times ``-omega^2``: on a flank its twist is a slope
    change, which eq. (1) takes as ``m``; two tones set the twist apart from the angle.)"""
    phases = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, 2)
    t = np.arange(round(duration_s * rate_hz)) / rate_hz
    angle, acc = np.zeros_like(t), np.zeros_like(t)
    for a, f, p in zip(amplitudes_deg, frequencies_hz, phases):
        w = 2.0 * np.pi * f
        angle += a * np.sin(w * t + p)
        acc -= a * w**2 * np.sin(w * t + p)
    return t, angle, acc


#: the prescribed motions of :func:`inertial_twist`: ``(duration_s, seed=...) -> (time_s, angle_deg,
#: acceleration_deg_s2)``
MOTIONS: dict[str, Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]] = {
    "two_tone": two_tone_motion,
    "point_to_point": point_to_point_motion,
}


def inertial_twist(
    seed: int = 0,
    duration_s: float = 120.0,
    inertia_over_stiffness_s2: float = INERTIA_OVER_STIFFNESS_S2,
    motion: str = "two_tone",
    play_deg: float = 0.5,
    ratio: float = 30.0,
    motor_bits: int = 14,
    load_bits: int = 17,
) -> Record:
    """A log without a torque column whose load twists by ``-(J / k) a`` while a flank is engaged.

    ``a`` is the analytic acceleration of the prescribed motion ``u`` (load side, deg/s^2; :data:`MOTIONS`),
    ``J / k`` is ``inertia_over_stiffness_s2``. Quasi-static: the load follows the twisted input
    ``w = u - (J / k) a`` through the backlash (eq. 1-3, slopes 1, ``play_deg`` split evenly), so on an
    engaged flank it lags the flank by the twist and in the dead band it rests where the flank released
    it, twist and all (a load does not jump). A flank only pushes: while the load decelerates, a Coulomb
    friction ``T_c >= J |a|`` on the output keeps it on the flank, and its wind-up ``T_c / k`` is a
    constant on each flank, part of the lost motion ``play_deg``. Encoders: ``motor_bits`` on the motor
    (``u * ratio``), ``load_bits`` on the load, quantised once; arbitrary zeros as in :func:`.rig.simulate_rig`.
    Returns ``(time_s, motor_deg, load_deg, torque_Nm)``, the torque all NaN.
    """
    t, u, acc = MOTIONS[motion](duration_s, seed=seed)
    twisted = u - inertia_over_stiffness_s2 * acc
    half = np.full(u.size, play_deg / 2.0)
    y = simulate_backlash_varying(twisted, 1.0, half, 1.0, half)
    return t, quantise(u * ratio + 1234.5, motor_bits), quantise(y - 321.0, load_bits), np.full(t.size, np.nan)

"""A two-mass test rig: the backlash is a consequence of the dynamics, not an assumed output map.

:mod:`.rig` writes the load angle with the estimator's own model (eq. 1-3 of the paper). This
simulator does not: it integrates the equations of motion of a geared drive, so play, torsional
wind-up and the flank that carries the torque all follow from physics, and an estimator that
assumes something else is tested on data it did not shape.

The drive (all angles load-side, degrees at the API, radians inside the integrator)::

    u(t)      prescribed motor angle referred to the load side (motor angle / ratio)
    delta     = u - y, the gear's torsion angle
    tau_g     = k (delta - c_right) + d (u' - y')   while delta > c_right  (right flank, tau_g >= 0)
              = k (delta + c_left)  + d (u' - y')   while delta < -c_left  (left flank,  tau_g <= 0)
              = 0                                   inside the dead band
    J y''     = tau_g - b y' - tau_c tanh(y' / w) - tau_ext(t)

``tau_g`` is the torque the gear transmits; teeth in contact only push (the damping term never
pulls a flank). The play is ``c_left + c_right``. On an engaged flank ``y = u - c_right - tau_g / k``
(right) or ``y = u + c_left - tau_g / k`` (left): the flank offset plus the wind-up, the way gear
makers' data sheets describe a hysteresis curve.

Two things a real drive adds, both off by default (the rig then is the one the load-aware path was
first tested on):

* **A hardening spring** (``stiffness_segments``): the data-sheet three-segment torsional stiffness
  of harmonic and cycloidal drives, ``K1`` up to the torque ``T1``, ``K2`` up to ``T2``, ``K3``
  above (N m/arcmin): ``k (delta - c)`` becomes the piecewise-linear spring through those segments.
* **What the torque sensor reads** (``sensor_friction_nm``, ``sensor_offset_nm``): the sensor sits on
  the driving side, with a friction torque ``Tf`` between it and the gear's flanks (bearings and
  seals of the input stage, moving with the motor), and reads a zero offset ``T0``::

      measured = tau_g + Tf tanh(u' / w) + T0 + noise

  so while the motor crosses the gap (no flank touches) the sensor reads ``T0 + Tf`` moving one way
  and ``T0 - Tf`` the other: the torques at which the right and the left flank engage. A model that
  takes zero torque as "no flank touches" reads the crossing as a loaded flank.

* **A second gap in series** (``second_gap_deg``): a gear train of two stages (a gearhead's two
  stages, or a stage and a cable drive). Part of the play sits between the motor and an intermediate
  shaft (inertia ``intermediate_inertia_kgm2``, held by the Coulomb friction ``intermediate_friction_nm``
  of its bearings), the rest between that shaft and the load, both meshes of stiffness ``k``::

      tau_a = mesh(u - x, the first gap)      tau_b = mesh(x - y, the second gap)
      J_x x'' = tau_a - tau_b - Tfx tanh(x' / w)        J y'' = tau_b - b y' - tau_c tanh(y' / w) - tau_ext

  A load torque that pushes the load the way the motor goes (an overrunning load, ``external_torque_nm``
  negative while rising) holds the second gap closed on its far side while the friction holds the
  intermediate shaft: after a reversal the load then follows with only the first gap crossed, until the
  load torque gives way and the load falls back across the second gap. The play of the train is the
  full crossing, ``play_deg``; the sensor reads ``tau_a``.

Units: seconds, degrees, N m, kg m^2, N m s/rad; stiffness in N m/arcmin at the API (the
data-sheet unit).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numba
import numpy as np

from ..errors import InvalidParameterError
from ..stream import SampleChunk
from .rig import RigRecording, quantise, rig_motion

#: arcminutes per degree
ARCMIN_PER_DEG = 60.0


@dataclass(kw_only=True)
class TwoMassRecording(RigRecording):
    """A :class:`~.rig.RigRecording` of the two-mass rig, with the transmitted torque.

    Attributes (beyond the base class)
    ----------------------------------
    torque_Nm : array
        Measured transmitted torque, N m (true torque plus sensor noise).
    torque_true_Nm : array
        True transmitted torque ``tau_g``, N m (0 inside the dead band).
    external_torque_Nm : array
        The external load torque applied at every sample, N m.
    stiffness_nm_per_arcmin : float
        True torsional stiffness of the engaged gear, N m/arcmin (the first segment's, ``K1``, for a
        hardening spring).
    stiffness_segments : tuple
        ``((K1, K2, K3) N m/arcmin, (T1, T2) N m)`` of a hardening spring; None for a linear one.
    sensor_friction_nm, sensor_offset_nm : float
        The friction between the torque sensor and the gear, and the sensor's zero offset, N m.
    """

    torque_Nm: np.ndarray
    torque_true_Nm: np.ndarray
    external_torque_Nm: np.ndarray
    stiffness_nm_per_arcmin: float
    stiffness_segments: tuple[tuple[float, float, float], tuple[float, float]] | None = None
    sensor_friction_nm: float = 0.0
    sensor_offset_nm: float = 0.0

    @property
    def engagement_torques_Nm(self) -> tuple[float, float]:
        """What the sensor reads when the (left, right) flank begins to carry torque, N m:
        ``T0 - Tf`` (the motor moving down) and ``T0 + Tf`` (moving up)."""
        return self.sensor_offset_nm - self.sensor_friction_nm, self.sensor_offset_nm + self.sensor_friction_nm

    def to_chunk(self) -> SampleChunk:
        """The recording as a :class:`SampleChunk` with its measured torque column."""
        n = self.time_s.size
        return SampleChunk(self.time_s, self.motor_deg, self.load_deg, self.torque_Nm, np.zeros(n, dtype=bool))

    def write_csv(
        self, path: str | os.PathLike[str], units: str = "deg", extra: Mapping[str, np.ndarray] | None = None
    ) -> None:
        """Write ``time,motor,load,torque`` (seconds, degrees or counts as
        :meth:`RigRecording.write_csv`, N m), then the ``extra`` columns. A ``.gz`` suffix compresses."""
        self._write_columns(path, units, {"torque": self.torque_Nm, **(extra or {})})

    @property
    def reversals_of_torque(self) -> int:
        """How many times the true transmitted torque changes sign (engaged flank to the other)."""
        engaged = np.sign(self.torque_true_Nm)
        engaged = engaged[engaged != 0]
        return int(np.count_nonzero(np.diff(engaged)))


@numba.njit(cache=True)
def _spring(torsion, knots, torques, ks):  # pragma: no cover - compiled
    """The torque of a flank wound up by ``torsion`` >= 0 (rad): piecewise linear, ``ks[j]`` (N m/rad)
    from the torsion ``knots[j]`` where it carries ``torques[j]`` (``knots[0] = torques[0] = 0``)."""
    j = knots.size - 1
    while torsion < knots[j]:
        j -= 1
    return torques[j] + ks[j] * (torsion - knots[j])


@numba.njit(cache=True)
def _integrate(
    u: np.ndarray,
    du: np.ndarray,
    tau_ext: np.ndarray,
    dt: float,
    k: float,
    knots: np.ndarray,
    torques: np.ndarray,
    ks: np.ndarray,
    d: float,
    c_left: float,
    c_right: float,
    inertia: float,
    viscous: float,
    coulomb: float,
    coulomb_width: float,
    coulomb_at_rad: np.ndarray,
    coulomb_scale: np.ndarray,
    y0: float,
    v0: float,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Semi-implicit Euler over the fine grid; load angle and transmitted torque (rad, N m) at each step's start.
    ``knots`` empty: the linear spring ``k``; else the segments of :func:`_spring`."""
    n = u.size
    y_out = np.empty(n)
    tau_out = np.empty(n)
    y, v = y0, v0
    linear = knots.size == 0
    for i in range(n):
        delta = u[i] - y
        if delta > c_right:
            spring = k * (delta - c_right) if linear else _spring(delta - c_right, knots, torques, ks)
            tau = max(0.0, spring + d * (du[i] - v))
        elif delta < -c_left:
            spring = k * (delta + c_left) if linear else -_spring(-c_left - delta, knots, torques, ks)
            tau = min(0.0, spring + d * (du[i] - v))
        else:
            tau = 0.0
        y_out[i] = y
        tau_out[i] = tau
        friction = coulomb * np.interp(y, coulomb_at_rad, coulomb_scale)
        acc = (tau - viscous * v - friction * math.tanh(v / coulomb_width) - tau_ext[i]) / inertia
        v += acc * dt
        y += v * dt
    return y_out, tau_out


@numba.njit(cache=True)
def _mesh(delta, c_left, c_right, k, d, slip):  # pragma: no cover - compiled
    """The torque a linear mesh of play ``c_left + c_right`` transmits at torsion ``delta`` (rad), its
    damping on the slip rate ``slip``; teeth only push."""
    if delta > c_right:
        return max(0.0, k * (delta - c_right) + d * slip)
    if delta < -c_left:
        return min(0.0, k * (delta + c_left) + d * slip)
    return 0.0


@numba.njit(cache=True)
def _integrate_two_gaps(
    u,
    du,
    tau_ext,
    dt,
    k,
    d,
    gaps,
    inertia_x,
    friction_x,
    inertia,
    viscous,
    coulomb,
    coulomb_width,
    coulomb_at_rad,
    coulomb_scale,
    y0,
    v0,
):  # pragma: no cover - compiled
    """Semi-implicit Euler of the train with two gaps in series (module docstring): load angle and the
    torque of the first mesh (rad, N m) at each step's start. ``gaps``: the first and the second gap's
    ``c_left``, ``c_right``, rad."""
    n = u.size
    y_out = np.empty(n)
    tau_out = np.empty(n)
    x, vx, y, v = y0, v0, y0, v0
    for i in range(n):
        tau_a = _mesh(u[i] - x, gaps[0], gaps[1], k, d, du[i] - vx)
        tau_b = _mesh(x - y, gaps[2], gaps[3], k, d, vx - v)
        y_out[i] = y
        tau_out[i] = tau_a
        friction = coulomb * np.interp(y, coulomb_at_rad, coulomb_scale)
        ax = (tau_a - tau_b - friction_x * math.tanh(vx / coulomb_width)) / inertia_x
        ay = (tau_b - viscous * v - friction * math.tanh(v / coulomb_width) - tau_ext[i]) / inertia
        vx += ax * dt
        x += vx * dt
        v += ay * dt
        y += v * dt
    return y_out, tau_out


def sine_motion(
    duration_s: float, rate_hz: float, amplitude_deg: float, frequency_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and a load-side reference angle (deg) following ``A sin(2 pi f t)``."""
    n = round(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    return t, amplitude_deg * np.sin(2.0 * np.pi * frequency_hz * t)


def _segments(segments: tuple | None, to_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The torsion knots (rad), their torques (N m) and the segments' stiffness (N m/rad) of a hardening
    spring ``((K1, K2, K3) N m/arcmin, (T1, T2) N m)``; three empty arrays for a linear one."""
    if segments is None:
        return np.empty(0), np.empty(0), np.empty(0)
    try:
        (k1, k2, k3), (t1, t2) = segments
        ks = np.array([k1, k2, k3], dtype=float) * to_rad
        torques = np.array([0.0, t1, t2], dtype=float)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"stiffness_segments must be ((K1, K2, K3), (T1, T2)), got {segments!r}") from None
    if not (np.all(np.isfinite(ks)) and np.all(ks > 0) and np.isfinite(t2) and 0 < t1 < t2):
        raise InvalidParameterError(f"stiffness_segments need stiffnesses > 0, torques 0 < T1 < T2, got {segments!r}")
    knots = np.concatenate(([0.0], np.cumsum(np.diff(torques) / ks[:2])))
    return knots, torques, ks


def _segments_given(segments: tuple) -> tuple[tuple[float, float, float], tuple[float, float]]:
    """``((K1, K2, K3), (T1, T2))`` as floats (checked by :func:`_segments`)."""
    (k1, k2, k3), (t1, t2) = segments
    return (float(k1), float(k2), float(k3)), (float(t1), float(t2))


def simulate_two_mass(
    duration_s: float = 30.0,
    rate_hz: float = 1000.0,
    ratio: float = 30.0,
    play_deg: float = 0.4,
    left_fraction: float = 0.5,
    stiffness_nm_per_arcmin: float = 0.1,
    contact_damping_ratio: float = 0.2,
    load_inertia_kgm2: float = 0.002,
    viscous_nms_per_rad: float = 0.3,
    coulomb_nm: float = 0.0,
    coulomb_profile: Callable[[np.ndarray], np.ndarray] | None = None,
    external_torque_nm: float | Callable[[np.ndarray], np.ndarray] = 0.0,
    torque_noise_nm: float = 0.005,
    stiffness_segments: tuple[tuple[float, float, float], tuple[float, float]] | None = None,
    sensor_friction_nm: float = 0.0,
    sensor_offset_nm: float = 0.0,
    motion: str | Callable[[float, float], tuple[np.ndarray, np.ndarray]] = "sine",
    amplitude_deg: float = 30.0,
    frequency_hz: float = 0.5,
    speed_deg_s: float = 30.0,
    motor_bits: int = 14,
    load_bits: int = 17,
    substeps: int = 20,
    motor_offset_deg: float = 1234.5,
    load_offset_deg: float = -321.0,
    seed: int | None = 0,
    second_gap_deg: float = 0.0,
    intermediate_inertia_kgm2: float = 0.0005,
    intermediate_friction_nm: float = 0.3,
) -> TwoMassRecording:
    """Simulate the two-mass rig described in the module docstring.

    Parameters
    ----------
    play_deg : float
        Total play ``c_left + c_right``, degrees (load side): of both gaps together with ``second_gap_deg``.
    second_gap_deg : float
        The part of ``play_deg`` between an intermediate shaft and the load (0: one gap, the two-mass rig;
        module docstring); ``left_fraction`` splits each gap, the spring is linear.
    intermediate_inertia_kgm2, intermediate_friction_nm : float
        The intermediate shaft's inertia and the Coulomb friction of its bearings (a second gap only).
    stiffness_nm_per_arcmin : float
        Torsional stiffness of the engaged gear, N m/arcmin (ignored with ``stiffness_segments``).
    stiffness_segments : ((K1, K2, K3), (T1, T2)), optional
        A hardening spring, the data-sheet way: ``K1`` N m/arcmin up to ``T1`` N m, ``K2`` up to
        ``T2``, ``K3`` above.
    sensor_friction_nm, sensor_offset_nm : float
        Friction torque between the torque sensor and the gear's flanks (on the driving side) and the
        sensor's zero offset, N m, both in what the sensor reads (module docstring); the load's
        motion does not change.
    contact_damping_ratio : float
        Damping of the engaged gear as a fraction of critical damping ``2 sqrt(k J)``.
    coulomb_profile : callable, optional
        The output's Coulomb friction as a multiple of ``coulomb_nm``, a function of the load angle
        (deg, the frame of the motion before the encoder offsets): a tight spot of a bearing or a
        cable stage. Tabulated every 0.05 deg over the motion's range (constant beyond it).
    external_torque_nm : float or callable
        External load torque, N m (a constant, or a function of time in seconds). A constant
        torque larger than the largest torque the motion needs holds the output against one
        flank all the time (a preloaded drive: the torque never reverses).
    motion : ``"sine"`` or ``"rig"``
        ``"sine"``: ``amplitude_deg * sin(2 pi frequency_hz t)`` (the measured rig's test);
        ``"rig"``: :func:`.rig.rig_motion`, continuous rotation with reversals at ``speed_deg_s``;
        a callable ``(duration_s, rate_hz) -> (time_s, angle_deg)``: that load-side reference.
    substeps : int
        Integration steps per output sample (the gear's natural frequency must stay well below
        ``rate_hz * substeps / (2 pi)``).
    """
    if play_deg < 0 or not 0.0 <= left_fraction <= 1.0 or stiffness_nm_per_arcmin <= 0 or load_inertia_kgm2 <= 0:
        raise InvalidParameterError("need play_deg >= 0, 0 <= left_fraction <= 1, stiffness > 0 and inertia > 0")
    if not (math.isfinite(sensor_friction_nm) and sensor_friction_nm >= 0 and math.isfinite(sensor_offset_nm)):
        given = f"{sensor_friction_nm!r}, {sensor_offset_nm!r}"
        raise InvalidParameterError(f"need a finite sensor friction >= 0 and offset, got {given}")
    if second_gap_deg and not (
        0.0 < second_gap_deg <= play_deg and stiffness_segments is None and intermediate_inertia_kgm2 > 0
    ):
        raise InvalidParameterError(
            "a second gap needs 0 < second_gap_deg <= play_deg, a linear spring and an intermediate inertia > 0"
        )
    if motion == "sine":
        t, u_deg = sine_motion(duration_s, rate_hz, amplitude_deg, frequency_hz)
    elif motion == "rig":
        t, u_deg = rig_motion(duration_s, rate_hz, speed_deg_s, seed=seed)
    elif callable(motion):
        t, u_deg = motion(duration_s, rate_hz)
    else:
        raise InvalidParameterError(f"motion must be 'sine' or 'rig', got {motion!r}")
    to_rad = ARCMIN_PER_DEG * 180.0 / math.pi  # N m/arcmin -> N m/rad
    knots, knot_torques, ks = _segments(stiffness_segments, to_rad)
    if stiffness_segments is not None:
        stiffness_nm_per_arcmin = float(stiffness_segments[0][0])
    k = stiffness_nm_per_arcmin * to_rad  # N m/rad
    lightest = min(load_inertia_kgm2, intermediate_inertia_kgm2) if second_gap_deg else load_inertia_kgm2
    natural_rad_s = math.sqrt(max([k, *ks.tolist()]) / lightest)
    if natural_rad_s / (rate_hz * substeps) > 0.2:
        raise InvalidParameterError(
            f"the gear's natural frequency ({natural_rad_s / 2 / math.pi:.0f} Hz) needs more than {substeps} "
            f"substeps at {rate_hz} Hz"
        )
    fine_t = np.arange(t.size * substeps) / (rate_hz * substeps)
    u_fine = np.radians(np.interp(fine_t, t, u_deg))
    du_fine = np.gradient(u_fine, fine_t) if fine_t.size > 1 else np.zeros_like(u_fine)
    ext = external_torque_nm(fine_t) if callable(external_torque_nm) else external_torque_nm
    tau_ext = np.broadcast_to(np.asarray(ext, dtype=float), fine_t.shape).copy()
    c_left, c_right = np.radians(left_fraction * play_deg), np.radians((1.0 - left_fraction) * play_deg)
    # start moving with the motor, wound up on the flank the external torque pushes against (mid-gap without one)
    y0 = u_fine[0] + (c_left if tau_ext[0] < 0 else -c_right if tau_ext[0] > 0 else 0.0) - tau_ext[0] / k
    damping = 2.0 * contact_damping_ratio * math.sqrt(k * load_inertia_kgm2)
    if coulomb_profile is None:
        at_deg, scale = np.zeros(1), np.ones(1)
    else:
        at_deg = np.arange(u_deg.min() - 5.0, u_deg.max() + 5.0, 0.05)
        scale = np.asarray(coulomb_profile(at_deg), dtype=float)
        if scale.shape != at_deg.shape or not np.all(np.isfinite(scale)) or np.any(scale < 0):
            raise InvalidParameterError("coulomb_profile must return one finite multiple >= 0 per angle")
    if second_gap_deg:
        first, second = np.radians(play_deg - second_gap_deg), np.radians(second_gap_deg)
        sides = np.array([left_fraction, 1.0 - left_fraction])
        gaps = np.concatenate((first * sides, second * sides))
        y_fine, tau_fine = _integrate_two_gaps(
            u_fine, du_fine, tau_ext, 1.0 / (rate_hz * substeps), k, damping, gaps, intermediate_inertia_kgm2,
            intermediate_friction_nm, load_inertia_kgm2, viscous_nms_per_rad, coulomb_nm, 1e-3, np.radians(at_deg),
            scale, u_fine[0], du_fine[0],
        )  # fmt: skip
    else:
        y_fine, tau_fine = _integrate(
            u_fine,
            du_fine,
            tau_ext,
            1.0 / (rate_hz * substeps),
            k,
            knots,
            knot_torques,
            ks,
            damping,
            c_left,
            c_right,
            load_inertia_kgm2,
            viscous_nms_per_rad,
            coulomb_nm,
            1e-3,
            np.radians(at_deg),
            scale,
            y0,
            du_fine[0],
        )
    pick = slice(0, None, substeps)  # the fine steps at the output instants
    y_deg, tau_true = np.degrees(y_fine[pick]), tau_fine[pick]
    rng = np.random.default_rng(None if seed is None else seed + 7)
    torque = tau_true + rng.normal(0.0, torque_noise_nm, t.size)
    if sensor_friction_nm or sensor_offset_nm:  # friction on the motor's side (1 mrad/s wide), zero offset
        torque += sensor_friction_nm * np.tanh(du_fine[pick] / 1e-3) + sensor_offset_nm
    n = t.size
    return TwoMassRecording(
        time_s=t,
        motor_deg=quantise(u_deg * ratio + motor_offset_deg, motor_bits),
        load_deg=quantise(y_deg + load_offset_deg, load_bits),
        u_true_deg=u_deg,
        play_deg=np.full(n, play_deg),
        c_left_deg=np.full(n, left_fraction * play_deg),
        c_right_deg=np.full(n, (1.0 - left_fraction) * play_deg),
        ratio=float(ratio),
        motor_bits=motor_bits,
        load_bits=load_bits,
        torque_Nm=torque,
        torque_true_Nm=tau_true,
        external_torque_Nm=tau_ext[pick].copy(),
        stiffness_nm_per_arcmin=float(stiffness_nm_per_arcmin),
        stiffness_segments=None if stiffness_segments is None else _segments_given(stiffness_segments),
        sensor_friction_nm=float(sensor_friction_nm),
        sensor_offset_nm=float(sensor_offset_nm),
    )

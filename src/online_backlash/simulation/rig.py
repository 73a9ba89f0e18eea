"""A synthetic gearbox test rig: rig-like motion, backlash that may wear, quantised encoders.

Used for the bundled demo recording, tests and benchmarks. The motion is continuous rotation
with reversals: the load-side reference speed alternates direction with random segment
lengths, forward segments longer than backward ones so the shaft turns many revolutions,
with smooth (raised-cosine) speed transitions.

Units: seconds, degrees (motor angle on the motor shaft, load angle on the load shaft),
degrees per second, encoder resolution in bits per revolution.
"""

from __future__ import annotations

import csv
import gzip
import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidParameterError
from ..model import simulate_backlash_varying
from ..stream import SampleChunk


@dataclass
class RigRecording:
    """A simulated recording with its ground truth.

    Attributes
    ----------
    time_s, motor_deg, load_deg : arrays
        What the encoders report (quantised, with noise and arbitrary zeros).
    u_true_deg : array
        True motor angle referred to the load side (no quantisation, no offset).
    play_deg : array
        True total play ``c_left + c_right`` at every sample, degrees (load side).
    c_left_deg, c_right_deg : arrays
        True dead-band widths, degrees.
    ratio : float
        Gear ratio motor:load.
    """

    time_s: np.ndarray
    motor_deg: np.ndarray
    load_deg: np.ndarray
    u_true_deg: np.ndarray
    play_deg: np.ndarray
    c_left_deg: np.ndarray
    c_right_deg: np.ndarray
    ratio: float

    def to_chunk(self) -> SampleChunk:
        """The recording as a :class:`SampleChunk` (what a log reader would give)."""
        n = self.time_s.size
        return SampleChunk(self.time_s, self.motor_deg, self.load_deg, np.full(n, np.nan), np.zeros(n, dtype=bool))

    motor_bits: int = 14
    load_bits: int = 17

    def motor_counts(self) -> np.ndarray:
        """Motor angle in motor-encoder counts (``2**motor_bits`` per motor revolution), multi-turn."""
        return np.rint(self.motor_deg / 360.0 * 2**self.motor_bits).astype(np.int64)

    def load_counts(self) -> np.ndarray:
        """Load angle in load-encoder counts (``2**load_bits`` per load revolution), multi-turn."""
        return np.rint(self.load_deg / 360.0 * 2**self.load_bits).astype(np.int64)

    def write_csv(
        self, path: str | os.PathLike[str], units: str = "deg", extra: Mapping[str, np.ndarray] | None = None
    ) -> None:
        """Write ``time,motor,load``: seconds and degrees (``units="deg"``, enough digits to keep
        every count) or seconds and encoder counts (``units="counts"``; read back with
        ``motor_cpr=2**motor_bits, load_cpr=2**load_bits``), then the ``extra`` columns (name ->
        values, 6 decimals). A ``.gz`` suffix compresses."""
        self._write_columns(path, units, extra)

    def _write_columns(
        self, path: str | os.PathLike[str], units: str, extra: Mapping[str, np.ndarray] | None = None
    ) -> None:
        """Write ``time,motor,load`` and the ``extra`` columns (a torque in N m, an hour meter in hours)."""
        opener = gzip.open if os.fspath(path).endswith(".gz") else open
        motor: Iterable[object]
        load: Iterable[object]
        if units == "deg":
            motor, load = (f"{v:.9f}" for v in self.motor_deg), (f"{v:.9f}" for v in self.load_deg)
        elif units == "counts":
            motor, load = self.motor_counts(), self.load_counts()
        else:
            raise InvalidParameterError(f"units must be 'deg' or 'counts', got {units!r}")
        columns: list[Iterable[object]] = [(f"{t:.6f}" for t in self.time_s), motor, load]
        header = ["time", "motor", "load"]
        for name, values in (extra or {}).items():
            columns.append(f"{v:.6f}" for v in values)
            header.append(name)
        with opener(path, "wt", newline="") as f:
            w = csv.writer(f)
            w.writerow(header)
            w.writerows(zip(*columns))


def rig_motion(
    duration_s: float,
    rate_hz: float = 1000.0,
    speed_deg_s: float = 30.0,
    reversal_s: tuple[float, float] = (2.0, 6.0),
    forward_bias: float = 1.5,
    seed: int | None = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and load-side reference angle (deg) of continuous rotation with reversals.

    Segment lengths are uniform in ``reversal_s``; forward segments are ``forward_bias`` times
    longer on average, so the shaft creeps forward over many revolutions.
    """
    rng = np.random.default_rng(seed)
    n = round(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    # direction and speed per segment
    direction = np.empty(n)
    i, sign = 0, 1.0
    while i < n:
        length = rng.uniform(*reversal_s) * (forward_bias if sign > 0 else 1.0)
        speed = speed_deg_s * rng.uniform(0.5, 1.5)
        j = min(n, i + max(2, int(length * rate_hz)))
        direction[i:j] = sign * speed
        i, sign = j, -sign
    # smooth the speed steps with a raised-cosine kernel of 0.2 s
    k = max(3, int(0.2 * rate_hz) | 1)
    kernel = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(k) / (k - 1))
    kernel /= kernel.sum()
    smooth_speed = np.convolve(np.pad(direction, (k // 2, k // 2), mode="edge"), kernel, mode="valid")
    return t, np.cumsum(smooth_speed) / rate_hz


def quantise(angle_deg: np.ndarray, bits: int) -> np.ndarray:
    """An ideal encoder of ``2**bits`` counts per revolution: the angle rounded down to a count, degrees."""
    step = 360.0 / 2**bits
    return np.floor(angle_deg / step) * step


def simulate_rig(
    duration_s: float = 60.0,
    rate_hz: float = 1000.0,
    ratio: float = 30.0,
    play_deg: float | Callable[[np.ndarray], np.ndarray] = 0.5,
    left_fraction: float = 0.5,
    slope: float = 1.0,
    motor_bits: int = 14,
    load_bits: int = 17,
    noise_counts: float = 2.0,
    speed_deg_s: float = 30.0,
    reversal_s: tuple[float, float] = (2.0, 6.0),
    motor_offset_deg: float = 1234.5,
    load_offset_deg: float = -321.0,
    seed: int | None = 0,
) -> RigRecording:
    """Simulate a geared rig with backlash, eq. (1)-(3), and quantised, noisy encoders.

    Parameters
    ----------
    play_deg : float or callable
        Total play (load side, degrees), or a function of time (s) giving it (wear).
    left_fraction : float
        Share of the play on the left flank (``c_left = left_fraction * play``).
    slope : float
        Both slopes ``m_left = m_right`` (1 for a gearbox whose ratio is exact).
    noise_counts : float
        Standard deviation of Gaussian noise on the load encoder, in load-encoder counts.
    motor_offset_deg, load_offset_deg : float
        Arbitrary encoder zeros.
    """
    rng = np.random.default_rng(None if seed is None else seed + 1)
    t, u = rig_motion(duration_s, rate_hz, speed_deg_s, reversal_s, seed=seed)
    play = np.broadcast_to(np.asarray(play_deg(t) if callable(play_deg) else play_deg, dtype=float), t.shape).copy()
    c_left = left_fraction * play
    c_right = play - c_left
    x = simulate_backlash_varying(u, slope, c_left, slope, c_right, x0=0.0)
    load_step = 360.0 / 2**load_bits
    load = quantise(x + load_offset_deg + rng.normal(0.0, noise_counts * load_step, t.size), load_bits)
    motor = quantise(u * ratio + motor_offset_deg, motor_bits)
    return RigRecording(t, motor, load, u, play, c_left, c_right, float(ratio), motor_bits, load_bits)

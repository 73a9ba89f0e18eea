"""Generic, data-driven terms for structure no named effect explains.

When the residual keeps structure that no effect of :mod:`.effects` accounts for, the loop
does not force a label on it: it reports it as *unexplained*, says in which variable it sits,
and still closes the loop with one of these flexible terms in that variable, so that the
error before and after is measured like any other. Both are linear in their coefficients
(they append columns to the regressor of eq. 8 / 14 exactly as the named effects do) and
implement :class:`~online_backlash.effect_terms.EffectTerms`.

* :class:`AngleHarmonicsPerFlank` -- a harmonic series in the load angle, separate for each
  direction of motion (each flank of the dead band).
* :class:`VelocityFunction` -- a smooth (piecewise-linear) function of the velocity.

Both can switch with the direction of motion and so can be nearly collinear with the play;
the loop's identifiability guard decides whether they may move it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._causal import motion_direction, velocity_deg_s
from ._scoring import Detection, DetectionData
from .effects import EffectBase, amplitudes_phases, harmonic_columns, select_orders


class AngleHarmonicsPerFlank(EffectBase):
    """A harmonic series in the load angle (approximated by ``u``), one set per direction of motion.

    Columns ``[sin(n u), cos(n u)] * [moving up]`` and ``... * [moving down]`` for every order.

    Parameters
    ----------
    orders : tuple of int
        Cycles per load revolution.
    window_samples : int
        Span of the difference that gives the direction of motion, samples.
    deadzone_deg : float
        A change of ``u`` smaller than this over the window keeps the last direction, deg.
    """

    name = "angle_harmonics_per_flank"

    def __init__(self, orders: tuple[int, ...] = (1,), window_samples: int = 10, deadzone_deg: float = 0.005) -> None:
        self.orders = tuple(orders)
        self.window_samples = int(window_samples)
        self.deadzone_deg = deadzone_deg
        self.history = self.window_samples
        super().__init__()

    def reset(self) -> None:
        super().reset()
        self._direction = 0.0

    @property
    def n_terms(self) -> int:
        return 4 * len(self.orders)

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        d = motion_direction(u, self.window_samples, self.deadzone_deg, self._direction)
        self._direction = float(d[-1])
        h = harmonic_columns(u, self.orders)
        return np.column_stack((h * (d > 0)[:, None], h * (d < 0)[:, None]))

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        k = 2 * len(self.orders)
        out = {}
        for flank, part in (("moving_up", coef[:k]), ("moving_down", coef[k:])):
            out[flank] = [
                {"order_per_rev": int(n), "amplitude_deg": a, "phase_deg": p}
                for n, (a, p) in zip(self.orders, amplitudes_phases(part))
            ]
        return out

    def location(self) -> str:
        """Where the structure sits, in words."""
        return f"against the load angle, orders {list(self.orders)} per revolution, different on each flank"

    @classmethod
    def detect(cls, data: DetectionData, max_order: int = 24, max_orders: int = 6) -> Detection | None:
        """Significant harmonics of the residual against the load angle, on either flank."""
        u = data.u_deg
        d = motion_direction(u, 10, 0.005, 0.0)
        up, down = (d > 0)[:, None], (d < 0)[:, None]

        def cols(n: float) -> np.ndarray:
            h = harmonic_columns(u, [n])
            out = np.empty((h.shape[0], 2 * h.shape[1]))
            np.multiply(h, up, out=out[:, : h.shape[1]])
            np.multiply(h, down, out=out[:, h.shape[1] :])
            return out

        orders = select_orders(data, cols, max_order, float(np.ptp(u)), max_orders)
        if not orders:
            return None
        effect = cls(tuple(sorted(int(n) for n in orders)))
        s = data.score(effect.input_side, effect.clone().terms(u, data.time_s, data.torque_Nm))
        return Detection(effect, s, f"residual against the load angle at orders {list(effect.orders)}, per flank")


class VelocityFunction(EffectBase):
    """A piecewise-linear function of the velocity of ``u`` (deg/s), zero at zero velocity.

    Columns are hat functions on ``knots_deg_s`` (the knot nearest 0 is left out, so the
    function is 0 there; beyond the outer knots it stays constant). Velocity is the causal
    difference over ``window_samples``.
    """

    name = "velocity_function"

    def __init__(self, knots_deg_s: tuple[float, ...] = (-30.0, 0.0, 30.0), window_samples: int = 10) -> None:
        self.knots_deg_s = tuple(float(k) for k in knots_deg_s)
        self.window_samples = int(window_samples)
        self.history = self.window_samples
        super().__init__()

    @property
    def _kept(self) -> np.ndarray:
        k = np.asarray(self.knots_deg_s)
        return np.delete(np.arange(k.size), int(np.argmin(np.abs(k))))

    @property
    def n_terms(self) -> int:
        return len(self.knots_deg_s) - 1

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        knots = np.asarray(self.knots_deg_s)
        v = np.clip(velocity_deg_s(u, t, self.window_samples), knots[0], knots[-1])
        basis = np.column_stack([np.interp(v, knots, np.eye(knots.size)[j]) for j in range(knots.size)])
        return basis[:, self._kept]

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        values = np.zeros(len(self.knots_deg_s))
        values[self._kept] = coef
        return {"knots_deg_s": list(self.knots_deg_s), "values_deg": [float(v) for v in values]}

    def location(self) -> str:
        """Where the structure sits, in words."""
        return f"against the velocity, {self.knots_deg_s[0]:.1f} to {self.knots_deg_s[-1]:.1f} deg/s"

    @classmethod
    def detect(cls, data: DetectionData, half_knots: int = 4) -> Detection | None:
        """A smooth function of velocity fitted to the residual."""
        v = velocity_deg_s(data.u_deg, data.time_s, 10)
        vmax = float(np.percentile(np.abs(v), 99))
        if vmax <= 0:
            return None
        effect = cls(tuple(np.linspace(-vmax, vmax, 2 * half_knots + 1)))
        s = data.score(effect.input_side, effect.clone().terms(data.u_deg, data.time_s, data.torque_Nm))
        return Detection(effect, s, f"residual depends on the velocity (|v| up to {vmax:.1f} deg/s)")


#: the generic terms, tried when structure remains that the named effects do not explain
GENERIC = (AngleHarmonicsPerFlank, VelocityFunction)

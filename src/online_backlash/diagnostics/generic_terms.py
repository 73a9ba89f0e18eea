"""Generic, data-driven terms for structure no named effect explains.

When the residual keeps structure that no effect of :mod:`.effects` accounts for, the loop
does not force a label on it: it reports it as *unexplained*, says in which variable it sits,
and still closes the loop with one of these flexible terms in that variable, so that the
error before and after is measured like any other. Both are linear in their coefficients
(they append columns to the regressor of eq. 8 / 14 exactly as the named effects do) and
implement :class:`~online_backlash.effect_terms.EffectTerms`.

* :class:`AngleHarmonicsPerFlank` -- a harmonic series in the load angle, separate for each
  direction of motion (each flank of the dead band).
* :class:`VelocityFunction` -- a smooth function of the velocity (a cubic spline).

Both can switch with the direction of motion and so can be nearly collinear with the play;
the loop's identifiability guard decides whether they may move it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._causal import velocity_deg_s
from ._effect_base import EffectBase, knots_and_window
from ._folds import DEADZONE_DEG, DIRECTION_WINDOW
from ._harmonics import harmonic_at_sources, harmonic_columns, held_per_flank
from ._per_flank import PerFlankTerms, record_direction
from ._scoring import Detection, DetectionData, Score
from ._speed import (
    MAX_INNER_KNOTS,
    VELOCITY_WINDOW,
    cardinal_columns,
    held_spline_columns,
    record_speed_knots,
    zero_knot,
)
from .effects import amplitudes_phases, select_orders


class AngleHarmonicsPerFlank(PerFlankTerms):
    """A harmonic series in the load angle (approximated by ``u``), one set per direction of motion.

    Columns ``[sin(n u), cos(n u)] * [moving up]`` and ``... * [moving down]`` for every order.

    Parameters
    ----------
    orders : tuple of int
        Cycles per load revolution.
    window_samples, deadzone_deg : int, float
        The direction of motion (:class:`._per_flank.PerFlankTerms`), samples and deg.
    """

    name = "angle_harmonics_per_flank"

    def __init__(
        self, orders: tuple[int, ...] = (1,), window_samples: int = DIRECTION_WINDOW, deadzone_deg: float = DEADZONE_DEG
    ) -> None:
        self.orders = tuple(orders)
        super().__init__(int(window_samples), deadzone_deg)

    @property
    def n_terms(self) -> int:
        return 4 * len(self.orders)

    def _shape(self, u: np.ndarray) -> np.ndarray:
        return harmonic_columns(u, self.orders)

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
        d = record_direction(data)
        up, down = d > 0, d < 0

        def held(n: int) -> np.ndarray:  # the columns of order n, held through the dead band
            columns, positions, rows = harmonic_at_sources(data, "load", u, n, max_order)
            return held_per_flank(
                columns, up if rows is None else up[rows], down if rows is None else down[rows], positions
            )

        orders = select_orders(data, held, max_order, float(np.ptp(u)), max_orders, held=True)
        if not orders:
            return None
        effect = cls(tuple(sorted(int(n) for n in orders)))
        s = data.score(effect.input_side, effect.clone().terms(u, data.time_s, data.torque_Nm))
        return Detection(effect, s, f"residual against the load angle at orders {list(effect.orders)}, per flank")


#: inner knots per direction of motion tried by :meth:`VelocityFunction.detect` (the count that
#: holds out best is kept)
KNOTS_PER_DIRECTION = tuple(range(1, MAX_INNER_KNOTS + 1))
#: a count of knots is worth its columns only if it removes this much more of the held-out squared
#: error than the fewer knots before it (share of the residual's), as an order must for the harmonics
KNOT_GAIN = 0.01


class VelocityFunction(EffectBase):
    """A smooth function of the velocity of ``u`` (deg/s), zero at zero velocity.

    A cubic spline through ``(knots_deg_s, values)``: the columns are the cardinal splines
    (the spline through 1 at one knot and 0 at the others), so the coefficients are the
    function's values at the knots, deg. The knot nearest 0 is left out, so the function is 0
    there; beyond the outer knots it stays constant. Velocity is the causal difference over
    ``window_samples``. A cubic spline follows a smooth nonlinear law of the speed (a lag that
    grows with the speed, a viscous or Stribeck friction, a velocity-dependent deflection)
    where a piecewise-linear function leaves its curvature between the knots: up to 2-3 times
    the noise floor on the two-mass rig, different on every stretch of constant speed
    (``docs/closing-the-loop.md``).

    Parameters
    ----------
    knots_deg_s : tuple of float
        Strictly increasing velocities, deg/s (at least two).
    window_samples : int
        Span of the difference that gives the velocity, samples.
    """

    name = "velocity_function"

    def __init__(self, knots_deg_s: tuple[float, ...] = (-30.0, 0.0, 30.0), window_samples: int = 10) -> None:
        knots = knots_and_window(knots_deg_s, 2, "velocities", "knots_deg_s", window_samples)
        self.knots_deg_s = tuple(float(k) for k in knots)
        self.window_samples = int(window_samples)
        self.history = self.window_samples
        super().__init__()

    @property
    def _kept(self) -> np.ndarray:
        return np.delete(np.arange(len(self.knots_deg_s)), zero_knot(self.knots_deg_s))

    @property
    def n_terms(self) -> int:
        return len(self.knots_deg_s) - 1

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        return cardinal_columns(self.knots_deg_s, velocity_deg_s(u, t, self.window_samples))

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        values = np.zeros(len(self.knots_deg_s))
        values[self._kept] = coef
        return {
            "knots_deg_s": list(self.knots_deg_s),
            "values_deg": [float(v) for v in values],
            "model": "cubic spline through (knots_deg_s, values_deg), not-a-knot ends, "
            "constant beyond the outer knots, added to the load angle",
        }

    def location(self) -> str:
        """Where the structure sits, in words."""
        return f"against the velocity, {self.knots_deg_s[0]:.1f} to {self.knots_deg_s[-1]:.1f} deg/s"

    @classmethod
    def detect(
        cls, data: DetectionData, knots_per_direction: tuple[int, ...] = KNOTS_PER_DIRECTION
    ) -> Detection | None:
        """A smooth function of velocity fitted to the residual.

        The knots are spread evenly over the speeds of each direction of motion, each direction
        up to its own outer knot (:func:`._speed.speed_knots`): every knot is then crossed in
        every reversal cycle, so its value is pinned down on the cycles held out too (the even
        grid to the 99th percentile of both directions pooled, used before, left knots beyond the
        slower direction's speeds: the fits without the one cycle that reached them were
        undetermined there, held-out gains of -1e277).
        The number of knots is the smallest that removes, on the held-out cycles, within
        :data:`KNOT_GAIN` of the squared error the best count removes (more knots than the law
        needs only blur the play: on the two-mass rig 4 inner knots per direction got the play
        held where 1 closes the same law).
        """
        scored: list[tuple[tuple[float, ...], VelocityFunction, Score]] = []
        for n in knots_per_direction:
            knots = record_speed_knots(data, n)
            if len(knots) < 2 or any(knots == k for k, _, _ in scored):
                continue
            effect = cls(knots, VELOCITY_WINDOW)
            # its columns (the same numbers as effect.terms on the record), held through the dead band
            scored.append((knots, effect, data.score(False, held_spline_columns(data, knots))))
        if not scored:
            return None
        # the fewest knots that hold out within KNOT_GAIN of the best count (the information
        # criterion where the record has too few cycles): more knots blur the play for nothing
        gains = [e[2].heldout_gain for e in scored if np.isfinite(e[2].heldout_gain)]
        if gains:
            _, effect, s = next(e for e in scored if e[2].heldout_gain >= max(gains) - KNOT_GAIN)
        else:
            _, effect, s = min(scored, key=lambda e: e[2].delta_bic)
        top = max(abs(effect.knots_deg_s[0]), abs(effect.knots_deg_s[-1]))
        return Detection(
            effect, s, f"residual depends on the velocity (|v| up to {top:.1f} deg/s, {effect.n_terms} knots)"
        )


#: the generic terms, tried when structure remains that the named effects do not explain
GENERIC = (AngleHarmonicsPerFlank, VelocityFunction)

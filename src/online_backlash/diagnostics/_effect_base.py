"""The base of the library's effects: parameters from ``__init__``, a causal window, ``clone`` and ``reset``.

Every effect of :mod:`.effects`, :mod:`.generic_terms` and :mod:`.dead_band` builds on :class:`EffectBase`
(the :class:`~online_backlash.effect_terms.EffectTerms` protocol). Units: degrees, seconds, N m.
"""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ._causal import CausalWindow

_COUNTS = {2: "two", 3: "three"}


def knots_and_window(knots: Any, least: int, what: str, name: str, window_samples: Any) -> np.ndarray:
    """``knots`` as a float array once they are at least ``least`` finite, strictly increasing ``what`` (the
    parameter ``name``) and ``window_samples`` at least 1; else :class:`InvalidParameterError` naming them."""
    values = np.asarray(knots, dtype=float)
    if values.ndim != 1 or values.size < least or not np.all(np.isfinite(values)) or np.any(np.diff(values) <= 0):
        raise InvalidParameterError(
            f"{name} must be at least {_COUNTS[least]} finite, strictly increasing {what}, got {knots!r}"
        )
    if int(window_samples) < 1:
        raise InvalidParameterError(f"window_samples must be >= 1, got {window_samples!r}")
    return values


class EffectBase:
    """Parameters from ``__init__`` (river style), a causal window, ``clone`` and ``reset``."""

    name = "effect"
    history = 0
    #: True for an effect on the input side of the backlash (held through the dead band in
    #: the output-error fit, see :mod:`.joint`); False for one on the load reading itself
    input_side = True

    def __init__(self) -> None:
        self._window = CausalWindow(self.history)
        self.reset()

    def get_params(self) -> dict[str, Any]:
        """The constructor arguments of this effect."""
        names = [p for p in inspect.signature(type(self).__init__).parameters if p != "self"]
        return {n: getattr(self, n) for n in names}

    def clone(self) -> EffectBase:
        """A fresh copy with the same settings and no stream history."""
        return type(self)(**self.get_params())

    def reset(self) -> None:
        """Forget the stream history (start of a record or after a gap)."""
        self._window.reset()

    @property
    def n_terms(self) -> int:
        """Number of regressor columns."""
        raise NotImplementedError

    def terms(self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray) -> np.ndarray:
        """Regressor columns ``(len(u_deg), n_terms)`` for consecutive samples (causal)."""
        u, t, q, n_past = self._window.extend(u_deg, time_s, torque_Nm)
        if u.size == 0:
            return np.empty((0, self.n_terms))
        cols = self._columns(u, t, q)
        self._window.keep(u, t, q)
        return np.ascontiguousarray(cols[n_past:]).reshape(-1, self.n_terms)

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        """The effect's parameters with units in their names, from its fitted coefficients."""
        raise NotImplementedError

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

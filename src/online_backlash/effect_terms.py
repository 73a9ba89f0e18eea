"""The protocol by which a model effect adds terms to the backlash model.

An effect found by the diagnostics (transmission error, delay, compliance, drift, ...) adds
to the predicted load angle a sum ``sum_k beta_k * term_k(t)`` whose terms are known functions
of the data and whose coefficients ``beta`` enter linearly. Appended to the regressor of
eq. (8) (or eq. 19), they keep the estimation quasi-linear: the switching functions still
select the active flank, and least squares (batch) or RLS (recursive) fits ``theta`` and
``beta`` jointly.

Terms are *causal* and *streaming-consistent*: an effect keeps what history it needs
(previous angle, time, ...) between calls, so calling :meth:`EffectTerms.terms` once on a whole
record gives the same rows as calling it on consecutive pieces, or one sample at a time.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class EffectTerms(Protocol):
    """What an estimator needs from an effect to fit it jointly with the backlash."""

    #: vocabulary name: "transmission_error", "delay", "compliance", "drift", or a generic one
    name: str

    @property
    def n_terms(self) -> int:
        """Number of regressor columns (coefficients) this effect adds."""

    def terms(self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray) -> np.ndarray:
        """Regressor columns, shape ``(len(u_deg), n_terms)``, for consecutive samples.

        ``u_deg`` is the motor angle referred to the load side (degrees), ``time_s`` in seconds,
        ``torque_Nm`` the measured torque (NaN where the source has none).
        """

    def reset(self) -> None:
        """Forget the stream history (start of a new record or after a gap)."""

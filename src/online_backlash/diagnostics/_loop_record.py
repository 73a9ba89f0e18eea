"""One record as :func:`.loop.diagnose` works on it: its angles, the base fit, the folds, the columns' caches.

Angles in degrees on the load side, time in seconds, torque in N m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimators import VorosBacklash
from ._folds import Folds
from ._initial_state import InitialState
from ._record_cache import RecordCache
from ._term_columns import TermColumns
from .residuals import NoiseFloor


@dataclass(frozen=True)
class LoopRecord:
    """The record and what every round of the loop reads of it (formed once, by :func:`.loop.diagnose`)."""

    #: the motor angle referred to the load side (motor angle / ratio), deg
    u_deg: np.ndarray
    #: the load angle as logged, deg
    load_deg: np.ndarray
    time_s: np.ndarray
    #: NaN where the log has no torque
    torque_Nm: np.ndarray
    #: gear ratio motor:load
    ratio: float
    #: the base fit (the "before"), ``refine=True``
    base: VorosBacklash
    #: ``u_deg`` in the base fit's centred frame, deg
    uc: np.ndarray
    #: the load angle in the base fit's centred frame with the estimated start taken out (every fit runs the
    #: model from rest), deg
    yc: np.ndarray
    #: the load's state in the dead band at the record's start
    start: InitialState
    #: the base fit's simulation residual, deg
    residual_before_deg: np.ndarray
    noise: NoiseFloor
    #: the median sample period, s, rounded to 1e-12 s
    period_s: float
    #: every reversal cycle (:func:`._folds.cycle_folds`)
    folds: Folds
    #: the cycles the candidates are scored and refitted on (:meth:`._folds.Folds.screen`; ``folds`` unscreened)
    screen: Folds
    #: columns that depend on the record only, shared by every round
    cache: RecordCache
    #: the columns of the terms taken, built once
    built: TermColumns

    @property
    def screen_rows(self) -> np.ndarray | None:
        """The samples of the candidates' refits: every sample of the screen's cycles (None: every sample)."""
        return self.screen.cycle_rows if self.screen.screened else None

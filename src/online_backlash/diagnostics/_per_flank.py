"""Columns split by the flank that drives: one set while ``u`` increases, one while it decreases.

The direction of motion is the sign of the change of ``u`` over a window, held inside a dead zone
(:func:`._causal.motion_direction`), carried between calls so that a record passed whole or in
pieces gives the same rows. Units: degrees.
"""

from __future__ import annotations

import numpy as np

from ._causal import motion_direction
from ._effect_base import EffectBase
from ._folds import DEADZONE_DEG, DIRECTION_WINDOW
from ._scoring import DetectionData


def record_direction(data: DetectionData) -> np.ndarray:
    """+1 / -1, the direction of motion of the record's ``u_deg`` (the folds' window and dead zone,
    :func:`._causal.motion_direction`), built once per record for every detector that splits by flank."""
    return data.memo(
        ("direction", DIRECTION_WINDOW, DEADZONE_DEG),
        lambda: motion_direction(data.u_deg, DIRECTION_WINDOW, DEADZONE_DEG, 0.0),
    )


class PerFlankTerms(EffectBase):
    """An effect whose columns are ``shape(u) * [moving up]`` then ``shape(u) * [moving down]``.

    Subclasses set their own parameters, call ``super().__init__(window_samples, deadzone_deg)`` and define
    :meth:`_shape`.

    Parameters
    ----------
    window_samples : int
        Span of the difference that gives the direction of motion, samples.
    deadzone_deg : float
        A change of ``u`` smaller than this over the window keeps the last direction, deg.
    """

    window_samples: int
    deadzone_deg: float

    def __init__(self, window_samples: int, deadzone_deg: float) -> None:
        self.window_samples = window_samples
        self.deadzone_deg = deadzone_deg
        self.history = self.window_samples
        super().__init__()

    def reset(self) -> None:
        super().reset()
        self._direction = 0.0

    def _shape(self, u: np.ndarray) -> np.ndarray:
        """The columns of one flank, ``(len(u), n_terms // 2)``."""
        raise NotImplementedError

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        d = motion_direction(u, self.window_samples, self.deadzone_deg, self._direction)
        self._direction = float(d[-1])
        h = self._shape(u)
        return np.column_stack((h * (d > 0)[:, None], h * (d < 0)[:, None]))

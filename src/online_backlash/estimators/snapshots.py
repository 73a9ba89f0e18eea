"""A recursive estimator's estimate at one instant (:class:`EstimateAt`): what ``learn_many(..., snapshot_at=)``
records and the pipeline and the play's per-cycle scatter read.

Units: degrees (load side); slopes dimensionless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["NOT_STARTED", "EstimateAt"]


@dataclass(frozen=True)
class EstimateAt:
    """A recursive estimator's estimate as it was at one instant (what the play's per-cycle scatter
    reads, :class:`~.uncertainty.RecursivePlayScatter`; ``learn_many(..., snapshot_at=)`` records it).

    Attributes
    ----------
    started : bool
        The estimator had started (before that the play and slopes are NaN, not read).
    backlash_deg : float
        Its play, degrees (load side).
    m_left, m_right : float
        Its flank slopes, eq. (1).
    level_deg : float
        The output level (the caller's frame, degrees) its play is read at, where that is not the frame's
        origin (:class:`~.backlash_rls.BacklashRLS` with ``full_engagement``); 0 otherwise.
    """

    started: bool
    backlash_deg: float
    m_left: float
    m_right: float
    level_deg: float = 0.0


#: The estimate of an estimator that has not started (:class:`EstimateAt`).
NOT_STARTED = EstimateAt(False, math.nan, math.nan, math.nan)

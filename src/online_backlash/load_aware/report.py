"""The load-aware keys of a fit's report: observability, torque reversals and the data-sheet figures.

One place turns a fitted estimator (torque-aware batch or recursive, or a kinematic one with its
:class:`~.observability.DwellTracker`) into the keys ``estimate --json`` carries
(:data:`online_backlash.rows.REPORT_KEYS`), and says in one line why a play is not observable.
Units: degrees, arc minutes, N m.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from .datasheet import datasheet_figures, line_figures
from .flank_fit import TorqueBacklash
from .observability import DwellTracker
from .torque_rls import TorqueBacklashRLS

__all__ = ["batch_keys", "has_torque", "kinematic_keys", "recursive_keys", "why_not_observable"]


def has_torque(torque_Nm: np.ndarray) -> bool:
    """True when the torque column is present (every value finite); False when it is absent (all NaN).

    Raises
    ------
    InvalidParameterError
        When only some values are finite (a non-finite torque must never reach an estimator).
    """
    finite = np.isfinite(np.asarray(torque_Nm, dtype=float))
    if finite.size and finite.all():
        return True
    if not finite.any():
        return False
    raise InvalidParameterError(f"the torque column has non-finite values, first at sample {int(np.flatnonzero(~finite)[0])}")


def _none_if_nan(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def batch_keys(est: TorqueBacklash, u: np.ndarray, y: np.ndarray, torque_Nm: np.ndarray, rated_torque_Nm: float | None) -> dict[str, Any]:
    """The keys of a torque-aware batch fit: observability and every data-sheet figure."""
    figures = datasheet_figures(est, u, y, torque_Nm, rated_torque_Nm)
    return {
        "play_observable": est.play_observable_,
        "torque_reversals": est.torque_reversals_,
        "backlash_lower_bound_deg": None,
        "backlash_std_deg": _none_if_nan(est.backlash_std_),
        "windup_separable": est.windup_separable_,
        "torque_sign": est.torque_sign_,
        **figures.as_dict(),
    }


def recursive_keys(est: TorqueBacklashRLS, rated_torque_Nm: float | None) -> dict[str, Any]:
    """The keys of a torque-aware recursive fit (the hysteresis loss needs the whole curve: None)."""
    left, right = est.flank_lines_()
    figures = line_figures(
        left, right, est.play_observable_, est.deadband_Nm_, est.torque_peaks_Nm_, rated_torque_Nm, est.operating_torque_Nm_,
        est.compliance_var_,
    )
    return {
        "play_observable": est.play_observable_,
        "torque_reversals": est.n_reversals_,
        "backlash_lower_bound_deg": None,
        "windup_separable": est.windup_separable_,
        "torque_sign": est.torque_sign,
        **figures.as_dict(),
    }


def kinematic_keys(tracker: DwellTracker) -> dict[str, Any]:
    """The keys of a fit without torque: observable when the load held still while the motor
    crossed the gap at some reversal; else the largest such travel as a lower bound."""
    observable = tracker.observable_
    bound = tracker.max_dwell_deg_
    return {
        "play_observable": observable,
        "torque_reversals": None,
        "backlash_lower_bound_deg": None if observable or bound <= 0 else bound,
    }


def why_not_observable(keys: dict[str, Any]) -> str | None:
    """One line saying why the play is not observable (None when it is)."""
    if keys.get("play_observable", True):
        return None
    if keys.get("torque_reversals") is None:
        return (
            "not observable: the load never held still while the motor crossed the gap (held against one flank, "
            "e.g. by a load torque); log the transmitted torque or run without the load"
        )
    if keys["torque_reversals"] == 0:
        return "not observable: the transmitted torque never reversed (a preloaded drive: the output stays on one flank)"
    return "not observable: one flank carried torque too briefly to place it"

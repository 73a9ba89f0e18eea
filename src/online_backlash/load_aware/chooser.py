"""The recursive play of a stream, its path chosen by the data (issue 27): :class:`PlayChooser`.

The pipeline (:mod:`online_backlash.pipeline`) of ``estimate`` and of ``track`` runs one estimator;
this is it. It wraps the estimator the log calls for (:class:`~online_backlash.estimators.BacklashRLS`
without a torque column, :class:`~.torque_rls.TorqueBacklashRLS` with one) and learns beside it the
evidence of the motion (:class:`~.observability.DwellTracker`, with the torque at each dwell's ends)
and, where the data are to decide (``play_method="auto"`` with a torque column), the kinematic
estimator on the same samples. After every block it moves the torque estimator's engagement
torques to what the dwells show (:func:`~.observability.engagement_torques`); at every row it
decides the path (:func:`~.choice.choose_play_method`) and what of its play may be reported
(:func:`online_backlash.physical.play_verdict`). Its state beside the wrapped estimator's is plain
JSON (:meth:`PlayChooser.state_dict`), so ``track`` checkpoints it with each row.

Units: degrees (load side), N m, seconds.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import NotExcitedError
from ..estimators import BacklashRLS
from ..estimators.base import EstimateAt
from .choice import (
    NO_TORQUE,
    PlayDecision,
    check_play_method,
    choose_play_method,
    kinematic_path,
    torque_dwell_test,
    torque_path,
)
from .observability import DwellTracker, engagement_torques

__all__ = ["PlayChooser"]


class PlayChooser:
    """A recursive estimator of the play whose path the data choose (module docstring).

    Parameters
    ----------
    estimator : BacklashRLS or TorqueBacklashRLS
        The estimator of the log's own path (the one ``track`` checkpoints as ``estimator``).
    play_method : {"auto", "torque", "kinematic"}
        ``auto``: the data decide (:mod:`.choice`); ``torque``, ``kinematic``: that path.
    companion : BacklashRLS, optional
        The kinematic estimator learning beside a torque estimator (``auto``).
    tracker : DwellTracker, optional
        The dwells so far (a resumed run); a new one by default.
    no_torque_why : str
        Why there is no torque path where there is none (a torque-like column not mapped, say).

    Attributes
    ----------
    decision_ : PlayDecision
        The path and why, and what of its play is reported (read anew at every access).
    """

    def __init__(
        self,
        estimator: Any,
        play_method: str = "auto",
        companion: BacklashRLS | None = None,
        tracker: DwellTracker | None = None,
        no_torque_why: str = NO_TORQUE,
    ) -> None:
        self.estimator = estimator
        self.play_method = check_play_method(play_method)
        self.companion = companion
        self.tracker = tracker if tracker is not None else DwellTracker()
        self.no_torque_why = no_torque_why
        self._decided: dict[float | None, PlayDecision] = {}  # since the last sample learned, by kinematic std

    @classmethod
    def beside(
        cls, estimator: Any, play_method: str = "auto", no_torque_why: str = NO_TORQUE, **kinematic_params: Any
    ) -> PlayChooser:
        """A chooser for a new ``estimator``: with a kinematic companion (``BacklashRLS(**kinematic_params)``)
        where a torque estimator's path is to be tested (``auto``)."""
        companion = BacklashRLS(**kinematic_params) if estimator.takes_torque and play_method == "auto" else None
        return cls(estimator, play_method, companion, None, no_torque_why)

    # -- the paths ----------------------------------------------------------------------------------
    @property
    def torque(self) -> Any:
        """The torque estimator, or None."""
        return self.estimator if self.estimator.takes_torque else None

    @property
    def kinematic(self) -> BacklashRLS | None:
        """The kinematic estimator (the wrapped one, or the companion), or None."""
        return self.companion if self.estimator.takes_torque else self.estimator

    def decide(self, kinematic_std_deg: float | None = None) -> PlayDecision:
        """The path and its verdict now; ``kinematic_std_deg`` replaces the kinematic estimator's own
        standard error (``estimate`` widens it by the per-cycle scatter,
        :class:`~online_backlash.estimators.uncertainty.RecursivePlayScatter`). Decided once between samples."""
        if kinematic_std_deg not in self._decided:
            self._decided[kinematic_std_deg] = self._decide(kinematic_std_deg)
        return self._decided[kinematic_std_deg]

    def _decide(self, kinematic_std_deg: float | None) -> PlayDecision:
        kin = self.kinematic
        kinematic = None
        if kin is not None:
            play = float(kin.backlash_) if kin.started else math.nan
            own = float(kin.backlash_std_) if kin.started else math.nan
            std = own if kinematic_std_deg is None else float(kinematic_std_deg)
            kinematic = kinematic_path(
                play, std, self.tracker, "the kinematic estimator has not started (its warm start waits for reversals)"
            )
        torque_est = self.torque if self.play_method != "kinematic" else None
        torque = None if torque_est is None or not torque_est.started else torque_path(torque_est, self.tracker)
        test = None if torque is None or not torque.observable else torque_dwell_test(torque_est, self.tracker)
        if torque is None and kinematic is None:
            raise NotExcitedError("no path of the play has started yet")
        return choose_play_method(self.play_method, torque, kinematic, test, self.no_torque_why)

    @property
    def decision_(self) -> PlayDecision:
        return self.decide()

    def chosen(self, decision: PlayDecision | None = None) -> Any:
        """The estimator of the path taken."""
        method = (decision or self.decide()).method
        return self.estimator if (method == "torque") == bool(self.estimator.takes_torque) else self.companion

    def __getattr__(self, name: str) -> Any:
        """The wrapped estimator's other attributes (``theta_``, ``warm_start_``, ``P_`` ...), as
        ``fit_recursive`` handed out the estimator itself before issue 27."""
        if name == "estimator":  # not set yet (a copy being built): no recursion
            raise AttributeError(name)
        return getattr(self.estimator, name)

    # -- the estimator's interface to the pipeline --------------------------------------------------
    @property
    def takes_torque(self) -> bool:
        return bool(self.estimator.takes_torque)

    @property
    def started(self) -> bool:
        return bool(self.estimator.started)

    @property
    def gaps_(self) -> Any:
        return self.estimator.gaps_

    @property
    def n_samples_seen_(self) -> int:
        return int(self.estimator.n_samples_seen_)

    @property
    def memory_reversals(self) -> float | None:
        kin = self.kinematic
        return None if kin is None else kin.memory_reversals

    def learn_many(
        self,
        u: np.ndarray,
        y: np.ndarray,
        after_gap: np.ndarray | None = None,
        *,
        time_s: np.ndarray | None = None,
        torque_Nm: np.ndarray | None = None,
        assume_finite: bool = False,
        snapshot_at: np.ndarray | None = None,
    ) -> list[EstimateAt] | None:
        """Learn a block: first the tracker (so the torque estimator reads the block with the engagement
        torques its dwells show), then the estimator and the companion. With ``snapshot_at``, the kinematic
        estimator's estimates there (what the per-cycle scatter of the kinematic play measures; the torque
        estimator states its own standard error)."""
        self._decided.clear()
        self.tracker.update(u, y, after_gap, torque_Nm if self.takes_torque else None)
        if self.takes_torque and self.play_method != "kinematic":
            self.estimator._ensure_valid()  # a cold start: started now, so the engagement torques can be set
            self.estimator.set_engagement_torques(*engagement_torques(self.tracker.dwells_))
        marks = self.estimator.learn_many(
            u, y, after_gap, time_s=time_s, torque_Nm=torque_Nm, assume_finite=assume_finite, snapshot_at=snapshot_at
        )
        if self.companion is not None:
            marks = self.companion.learn_many(
                u, y, after_gap, time_s=time_s, assume_finite=assume_finite, snapshot_at=snapshot_at
            )
        return marks

    def mark_gap(self) -> None:
        """A new log: none of the three reads the next sample as motion from the last."""
        self._decided.clear()
        self.estimator.mark_gap()
        if self.companion is not None:
            self.companion.mark_gap()
        self.tracker.mark_gap()

    def force_start(self) -> None:
        """Start the estimator on what it buffered (NotExcitedError as it gives it); the companion if it can."""
        self._decided.clear()
        self.estimator.force_start()
        if self.companion is not None:
            try:
                self.companion.force_start()
            except NotExcitedError:
                pass  # the kinematic path stays "not started": the decision says so

    @property
    def backlash_(self) -> float:
        """The play as reported now, degrees (NaN where it is not: :func:`online_backlash.physical.play_verdict`)."""
        value = self.decide().verdict.value
        return math.nan if value is None else value

    @property
    def backlash_std_(self) -> float:
        """Its standard error, degrees (NaN where the play is not reported)."""
        std = self.decide().verdict.std
        return math.nan if std is None else std

    def estimate_now(self) -> EstimateAt:
        return self.estimator.estimate_now()

    # -- what a row carries -------------------------------------------------------------------------
    def row_fields(self) -> dict[str, Any] | None:
        """The columns of an :class:`~online_backlash.output_columns.EstimateRow` (but its time): the path taken,
        why, and its play as :func:`~online_backlash.physical.play_verdict` lets it be reported; None
        while that path has no estimate at all (no row is due)."""
        decision = self.decide()
        est = self.chosen(decision)
        if est is None or not est.started or not math.isfinite(float(est.backlash_)):
            return None
        keys = decision.keys()
        torque = self.torque
        separable = decision.method == "torque"
        return {
            **keys,
            "n_samples": int(self.estimator.n_samples_seen_),
            "backlash_deg": math.nan if keys["backlash_deg"] is None else keys["backlash_deg"],
            "backlash_std_deg": math.nan if keys["backlash_std_deg"] is None else keys["backlash_std_deg"],
            "c_left_deg": float(est.c_left_),
            "c_right_deg": float(est.c_right_),
            "m_left": float(est.m_left_),
            "m_right": float(est.m_right_),
            "residual_rms_deg": float(est.residual_rms_),
            "n_reversals": int(est.n_reversals_),
            "torque_reversals": None if torque is None else int(torque.n_reversals_),
            "stiffness_left_nm_per_arcmin": float(torque.stiffness_left_nm_per_arcmin_) if separable else None,
            "stiffness_right_nm_per_arcmin": float(torque.stiffness_right_nm_per_arcmin_) if separable else None,
        }

    # -- saved state ----------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """The chooser's own state (the wrapped estimator saves its own), plain JSON types."""
        return {
            "play_method": self.play_method, "no_torque_why": self.no_torque_why, "tracker": self.tracker.state_dict(),
            "companion": None if self.companion is None else self.companion.state_dict(),
        }  # fmt: skip

    @classmethod
    def from_state(cls, estimator: Any, d: dict[str, Any] | None, play_method: str = "auto") -> PlayChooser:
        """The chooser saved by :meth:`state_dict` around the restored ``estimator``; from a checkpoint
        written before choosers (``d`` None), a new one with ``play_method`` (no companion: the
        kinematic path starts with the next log)."""
        if d is None:
            return cls(estimator, play_method)
        companion = None if d["companion"] is None else BacklashRLS.from_state(d["companion"])
        tracker = DwellTracker.from_state(d["tracker"])
        return cls(estimator, d["play_method"], companion, tracker, d["no_torque_why"])  # type: ignore[arg-type]

"""What the loop found in one record: the terms it added (:class:`AddedTerm`) and the whole (:class:`Diagnosis`).

Both are results: :func:`.loop.diagnose` fills them, :mod:`.report` and :mod:`.plot` read them, and
``as_dict`` gives the JSON contract of ``online-backlash diagnose --json``. Angles in degrees on the
load side, time in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..estimators import VorosBacklash
from ._causal import sample_period_s, savgol_derivative
from ._initial_state import InitialState
from ._scoring import BIC_THRESHOLD, MIN_GAIN, Detection, DetectionData
from .joint import MAX_PLAY_INFLATION, MAX_PLAY_STD_SHARE, JointFit
from .residuals import NoiseFloor, Profile, one_step_residual, profile


@dataclass
class AddedTerm:
    """One term added by the loop.

    ``kind`` is ``"effect"`` (a named effect of the library) or ``"unexplained"`` (a generic term
    closing structure no named effect explains), ``number`` its place in the order added (from 1).
    ``parameters`` come from the final joint fit;
    ``rms_before_deg`` and ``rms_after_deg`` are the residual RMS just before and after adding it.
    """

    kind: str
    effect: Any
    detection: Detection
    rms_before_deg: float
    rms_after_deg: float
    play_before_deg: float
    play_after_deg: float
    play_inflation: float
    play_std_deg: float
    play_held: bool
    number: int = 0
    parameters: dict[str, Any] = field(default_factory=dict)
    #: the simulation residual after this term was added, deg
    residual_after_deg: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)
    #: how the held-out cycles were chosen (``folds``, ``cycles``, ``split``)
    heldout_split: dict[str, Any] = field(default_factory=dict)
    #: held-out gain of this term given all the others, in the final model (NaN if not measured)
    heldout_gain_final: float = float("nan")
    #: named effects that explain the same part of the residual (kind ``"not_separable"``)
    rivals: tuple[str, ...] = ()
    #: the fit just before this term came in and the terms it had then: what ``detection`` was
    #: scored on (see :func:`._final_model.rescore_retuned`)
    scored_on: tuple[JointFit, tuple[Any, ...]] | None = field(default=None, repr=False)
    #: the detection data of ``scored_on`` over every sample, kept while the loop runs for a term whose
    #: setting a later round may move (``neighbours``): :func:`._final_model.rescore_retuned` scores the
    #: final setting on it
    scored_data: DetectionData | None = field(default=None, repr=False)
    #: True when a later term moved this term's setting (:func:`._refits.walk_settings`): ``effect`` and
    #: the evidence are of the final setting
    retuned: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The JSON object of this term (``name``, ``parameters``, ``rms_before_deg``, ``rms_after_deg``,
        ``evidence``)."""
        s = self.detection.score
        evidence: dict[str, Any] = {
            "summary": self.detection.evidence,
            "statistic": "delta_bic_eff",
            "delta_bic_eff": s.delta_bic,
            "threshold": BIC_THRESHOLD,
            "share_of_residual_explained": s.gain,
            "heldout_gain": s.heldout_gain,
            "heldout_gain_in_final_model": self.heldout_gain_final,
            "heldout_split": self.heldout_split,
            "effective_samples": s.n_eff,
            "own_variance_share": s.own_share,
            "play_variance_inflation": self.play_inflation,
            "play_std_deg": self.play_std_deg,
            "play_separable": not self.play_held,
            "retuned_by_later_terms": self.retuned,
        }
        if self.play_held:
            evidence["note"] = (
                "the data cannot separate this term from the play (play variance inflation "
                f"{self.play_inflation:.1f}, limit {MAX_PLAY_INFLATION:.0f}; play standard error "
                f"{self.play_std_deg:.2g} deg, limit {MAX_PLAY_STD_SHARE:.1%} of the play), "
                "so the play was held at its value without the term"
            )
        out = {
            "step": self.number,
            "name": "not_separable" if self.kind == "not_separable" else self.effect.name,
            "parameters": self.parameters,
            "rms_before_deg": self.rms_before_deg,
            "rms_after_deg": self.rms_after_deg,
            "backlash_before_deg": self.play_before_deg,
            "backlash_after_deg": self.play_after_deg,
            "evidence": evidence,
        }
        if self.kind == "unexplained":
            out["where"] = self.effect.location()
        if self.kind == "not_separable":
            names = [self.effect.name, *self.rivals]
            out["candidates"] = names
            out["closed_with"] = self.effect.name
            out["where"] = (
                f"{' and '.join(names)} explain the same part of the residual (each adds less than "
                f"{MIN_GAIN:.0%} once the other is in): not separable on this record; closed with {self.effect.name}"
            )
        return out


@dataclass
class Diagnosis:
    """What the loop found in one record. Angles in degrees (load side).

    Attributes
    ----------
    base : VorosBacklash
        The base fit (the "before").
    final : JointFit
        The backlash and all added terms fitted jointly (the "after"), centred frame.
    steps : list of AddedTerm
        The terms in the order added.
    noise : NoiseFloor
    residual_before_deg, residual_after_deg : arrays
        Simulation residuals of the base and final models.
    u_deg, load_deg, time_s : arrays
        The referred motor angle, the load angle and the time of the record.
    ratio : float
        Gear ratio motor:load.
    initial_state : InitialState
        The load's state in the dead band at the record's start (a nuisance of the base fit, taken
        out of the residual before and after alike; not an effect).
    """

    base: VorosBacklash
    final: JointFit
    steps: list[AddedTerm]
    noise: NoiseFloor
    residual_before_deg: np.ndarray
    residual_after_deg: np.ndarray
    u_deg: np.ndarray
    load_deg: np.ndarray
    time_s: np.ndarray
    ratio: float
    torque_Nm: np.ndarray | None = None
    initial_state: InitialState = field(default_factory=InitialState)
    #: reversal cycles the candidates were scored and refitted on (a screen of a long record,
    #: :meth:`._folds.Folds.screen`); None: every cycle
    screened_cycles: int | None = None
    #: reversal cycles in the record (:func:`._folds.cycle_folds`)
    cycles: int = 0

    @property
    def effects(self) -> list[Any]:
        """Fresh copies of the named effects found (for ``BacklashRLS(effects=...)``)."""
        return [s.effect.clone() for s in self.steps if s.kind == "effect"]

    @property
    def all_terms(self) -> list[Any]:
        """Fresh copies of every term added, named and generic."""
        return [s.effect.clone() for s in self.steps]

    @property
    def rms_before_deg(self) -> float:
        return float(np.sqrt(np.mean(self.residual_before_deg**2)))

    @property
    def rms_after_deg(self) -> float:
        return float(np.sqrt(np.mean(self.residual_after_deg**2)))

    @property
    def one_step_residual_deg(self) -> np.ndarray:
        """The equation error of eq. (14) with the base fit's parameters, deg."""
        return one_step_residual(self.base.params_, self.u_deg - self.base.u_ref_, self.load_deg - self.base.y_ref_)

    def profiles(self, bins: int = 40) -> dict[str, tuple[Profile, Profile]]:
        """The simulation residual before and after, binned against time, load angle, motor angle and velocity."""
        period = sample_period_s(self.time_s)
        variables = {
            "time": (self.time_s, "s"),
            "load angle": (self.load_deg, "deg"),
            "motor angle": (self.u_deg * self.ratio, "deg"),
            "velocity": (np.gradient(self.u_deg, period), "deg/s"),
        }
        return {
            name: (
                profile(self.residual_before_deg, v, name, unit, bins),
                profile(self.residual_after_deg, v, name, unit, bins),
            )
            for name, (v, unit) in variables.items()
        }

    def step_residuals(self) -> list[tuple[AddedTerm, np.ndarray, np.ndarray]]:
        """Every step with the simulation residual just before and just after it, deg."""
        out, before = [], self.residual_before_deg
        for s in self.steps:
            out.append((s, before, s.residual_after_deg))
            before = s.residual_after_deg
        return out

    def axis(self, step: AddedTerm) -> tuple[str, str, np.ndarray]:
        """The variable a term acts along, ``(name, unit, values)``: load angle (transmission error,
        per-flank harmonics), velocity (delay, velocity function), torque or acceleration
        (compliance), time (drift), time since the switching functions changed (dead band motion)."""
        name = step.effect.name
        period = sample_period_s(self.time_s)
        if name == "compliance":
            if getattr(step.effect, "proxy", "") == "torque" and self.torque_Nm is not None:
                return "torque", "N m", np.nan_to_num(self.torque_Nm, nan=0.0)
            return "acceleration", "deg/s^2", savgol_derivative(self.u_deg, self.time_s, step.effect.window_samples, 2)
        if name == "drift":
            return "time", "s", self.time_s
        if name == "dead_band_motion":
            clock = step.effect.switch_clock(self.u_deg, self.time_s)
            return "time since the flank left (< 0) or engaged (> 0)", "s", clock
        if name in ("delay", "velocity_function"):
            return "velocity", "deg/s", np.gradient(self.u_deg, period)
        return "load angle", "deg", self.load_deg

    def as_dict(self) -> dict[str, Any]:
        """The JSON contract of ``online-backlash diagnose --json``."""
        return {
            "rms_before_deg": self.rms_before_deg,
            "rms_after_deg": self.rms_after_deg,
            "noise_floor_deg": self.noise.floor_deg,
            "backlash_before_deg": self.base.backlash_,
            "backlash_after_deg": self.final.params.play,
            "effects": [s.as_dict() for s in self.steps if s.kind == "effect"],
            "unexplained": [s.as_dict() for s in self.steps if s.kind != "effect"],
            "samples": int(self.u_deg.size),
            "load_step_deg": self.noise.step_deg,
            "load_noise_deg": self.noise.noise_deg,
            "initial_state": self.initial_state.as_dict(),
            "screened_cycles": self.screened_cycles,
        }

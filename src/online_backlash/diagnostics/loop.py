"""The selection loop: fit, look at the residual, add the effect it shows, refit, repeat.

1. Fit the base model, the four backlash parameters of eq. (1) refitted on the simulation
   (free-run) residual (:class:`~online_backlash.estimators.VorosBacklash` with
   ``refine=True``). Its residual is the "before": the paper's equation-error estimate alone
   leaves a larger one and would flatter every effect.
2. Score every effect of the library and every generic term on the residual (an information
   criterion with an effective sample size, plus a minimum share explained, see
   :mod:`._scoring`).
3. Refit the backlash and all terms jointly by output error (:func:`.joint.fit_guarded`), once
   with the best significant named effect and once with the best generic term; keep the named
   effect unless the generic term leaves clearly less (then the structure is *unexplained*: it
   is reported with where it sits and closed with that generic term). If the new terms blur
   the play (variance inflation above :data:`.joint.MAX_PLAY_INFLATION` or standard error
   above :data:`.joint.MAX_PLAY_STD_SHARE` of the play), the play is held and the report says
   so. A term whose joint refit does not remove at least ``min_gain`` of the mean square
   residual is refused (the linear score can promise more than the refit delivers when the
   play is held).
4. Repeat until nothing is significant or the residual reaches the noise floor.

Angles in degrees on the load side, time in seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..estimators import VorosBacklash
from ..estimators._validation import check_int, check_real
from ..stream import SampleChunk
from ._scoring import BIC_THRESHOLD, MIN_GAIN, Detection, DetectionData
from .effects import LIBRARY
from .generic import GENERIC
from .joint import MAX_PLAY_INFLATION, MAX_PLAY_STD_SHARE, JointFit, engaged_index, fit_guarded, hold_columns, play_sensitivity
from .residuals import NoiseFloor, Profile, noise_floor, one_step_residual, profile, simulation_residual


@dataclass
class Step:
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

    def as_dict(self) -> dict[str, Any]:
        """The JSON object of this term (``name``, ``parameters``, ``rms_before_deg``, ``rms_after_deg``, ``evidence``)."""
        s = self.detection.score
        evidence: dict[str, Any] = {
            "summary": self.detection.evidence,
            "statistic": "delta_bic_eff",
            "delta_bic_eff": s.delta_bic,
            "threshold": BIC_THRESHOLD,
            "share_of_residual_explained": s.gain,
            "effective_samples": s.n_eff,
            "own_variance_share": s.own_share,
            "play_variance_inflation": self.play_inflation,
            "play_std_deg": self.play_std_deg,
            "play_separable": not self.play_held,
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
            "name": self.effect.name,
            "parameters": self.parameters,
            "rms_before_deg": self.rms_before_deg,
            "rms_after_deg": self.rms_after_deg,
            "backlash_before_deg": self.play_before_deg,
            "backlash_after_deg": self.play_after_deg,
            "evidence": evidence,
        }
        if self.kind == "unexplained":
            out["where"] = self.effect.location()
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
    steps : list of Step
        The terms in the order added.
    noise : NoiseFloor
    residual_before_deg, residual_after_deg : arrays
        Simulation residuals of the base and final models.
    u_deg, load_deg, time_s : arrays
        The referred motor angle, the load angle and the time of the record.
    ratio : float
        Gear ratio motor:load.
    """

    base: VorosBacklash
    final: JointFit
    steps: list[Step]
    noise: NoiseFloor
    residual_before_deg: np.ndarray
    residual_after_deg: np.ndarray
    u_deg: np.ndarray
    load_deg: np.ndarray
    time_s: np.ndarray
    ratio: float

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
        period = float(np.median(np.diff(self.time_s))) if self.time_s.size > 1 else 1.0
        variables = {
            "time": (self.time_s, "s"),
            "load angle": (self.load_deg, "deg"),
            "motor angle": (self.u_deg * self.ratio, "deg"),
            "velocity": (np.gradient(self.u_deg, period), "deg/s"),
        }
        return {
            name: (profile(self.residual_before_deg, v, name, unit, bins), profile(self.residual_after_deg, v, name, unit, bins))
            for name, (v, unit) in variables.items()
        }

    def as_dict(self) -> dict[str, Any]:
        """The JSON contract of ``online-backlash diagnose --json``."""
        return {
            "rms_before_deg": self.rms_before_deg,
            "rms_after_deg": self.rms_after_deg,
            "noise_floor_deg": self.noise.floor_deg,
            "backlash_before_deg": self.base.backlash_,
            "backlash_after_deg": self.final.params.play,
            "effects": [s.as_dict() for s in self.steps if s.kind == "effect"],
            "unexplained": [s.as_dict() for s in self.steps if s.kind == "unexplained"],
            "samples": int(self.u_deg.size),
            "load_step_deg": self.noise.step_deg,
            "load_noise_deg": self.noise.noise_deg,
        }


def _columns(terms: Sequence[Any], u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
    cols = [e.clone().terms(u, t, q) for e in terms]
    return np.column_stack(cols) if cols else np.empty((u.size, 0))


def _held(terms: Sequence[Any]) -> np.ndarray:
    """Which columns are held through the dead band (input-side effects)."""
    return np.concatenate([np.full(e.n_terms, bool(e.input_side)) for e in terms]) if terms else np.zeros(0, bool)


def _significant(found: list[Detection | None], bic_threshold: float, min_gain: float) -> Detection | None:
    ok = [d for d in found if d is not None and d.score.significant(bic_threshold, min_gain)]
    return max(ok, key=lambda d: d.score.gain, default=None)


def diagnose(
    chunk: SampleChunk,
    ratio: float,
    *,
    max_terms: int = 6,
    bic_threshold: float = BIC_THRESHOLD,
    min_gain: float = MIN_GAIN,
    label_ratio: float = 1.1,
    floor_ratio: float = 1.1,
) -> Diagnosis:
    """Run the loop on a record in memory.

    Parameters
    ----------
    chunk : SampleChunk
        Time (s), motor angle (deg, motor shaft), load angle (deg), torque (N m, NaN if none).
    ratio : float
        Gear ratio motor:load (negative for a reversing stage).
    max_terms : int
        Most terms (named and generic) added.
    bic_threshold, min_gain : float
        Significance: criterion below ``bic_threshold`` and at least ``min_gain`` of the
        residual's mean square explained.
    label_ratio : float
        A named effect is chosen only if, after the joint refit, the mean square residual it
        leaves is at most this many times what the best generic term leaves; otherwise the
        structure is reported as unexplained (and closed with the generic term).
    floor_ratio : float
        Stop when the residual RMS is within this factor of the noise floor.

    Raises
    ------
    NotExcitedError
        When the record does not engage both flanks.
    """
    check_int("max_terms", max_terms, 0)
    check_real("min_gain", min_gain, 0.0, low_open=False)
    check_real("label_ratio", label_ratio, 1.0, low_open=False)
    check_real("floor_ratio", floor_ratio, 1.0, low_open=False)
    u, y = (np.asarray(v, dtype=float) for v in chunk.referred(ratio))
    t = np.asarray(chunk.time_s, dtype=float)
    q = np.asarray(chunk.torque_Nm, dtype=float)
    base = VorosBacklash(refine=True, origin="first").fit(u, y)  # encoder zeros are arbitrary
    uc, yc = u - base.u_ref_, y - base.y_ref_
    noise = noise_floor(y)
    period = round(float(np.median(np.diff(t))), 12) if t.size > 1 else 1.0  # 0.001, not 0.000999999...
    before = simulation_residual(base.params_, uc, yc)
    current = JointFit(base.params_, np.empty(0), before, 1.0, float("nan"), False)
    steps: list[Step] = []
    refused: set[type] = set()
    while len(steps) < max_terms and current.rms_deg > floor_ratio * noise.floor_deg:
        taken = {type(s.effect) for s in steps} | refused
        g, others = play_sensitivity(uc, current.params)
        index = engaged_index(uc, current.params)
        nuisance = np.column_stack((others, g))
        done = [s.effect for s in steps]
        if done:  # the terms already added may move too
            nuisance = np.column_stack((nuisance, hold_columns(_columns(done, u, t, q), _held(done), index)))
        data = DetectionData(u, t, q, current.residual_deg, float(ratio), period, nuisance, index, others.shape[1] + 1)
        named = _significant([c.detect(data) for c in LIBRARY if c not in taken], bic_threshold, min_gain)
        generic = _significant([c.detect(data) for c in GENERIC if c not in taken], bic_threshold, min_gain)

        def refit(found: Detection, done: list = done, current: JointFit = current) -> JointFit:
            terms = [*done, found.effect]
            return fit_guarded(uc, yc, _columns(terms, u, t, q), current.params, _held(terms))

        if named is None and generic is None:
            break
        # a named effect must do about as well as a flexible generic term in the joint refit
        fit_named = refit(named) if named is not None else None
        fit_generic = refit(generic) if generic is not None else None
        kind: str
        chosen: Detection
        fit: JointFit
        if named is not None and fit_named is not None and (fit_generic is None or fit_named.rms_deg**2 <= label_ratio * fit_generic.rms_deg**2):
            kind, chosen, fit = "effect", named, fit_named
        elif generic is not None and fit_generic is not None:
            kind, chosen, fit = "unexplained", generic, fit_generic
        else:  # unreachable: one of the two was found above
            break
        if fit.rms_deg**2 > (1.0 - min_gain) * current.rms_deg**2:
            refused.add(type(chosen.effect))  # the refit does not realise the gain: try the others
            continue
        steps.append(
            Step(
                kind, chosen.effect, chosen, current.rms_deg, fit.rms_deg, current.params.play, fit.params.play,
                fit.play_inflation, fit.play_std_deg, fit.play_held, len(steps) + 1,
            )
        )
        current = fit
    _describe(steps, current)
    return Diagnosis(base, current, steps, noise, before, current.residual_deg, u, y, t, float(ratio))


def _describe(steps: list[Step], final: JointFit) -> None:
    """Each step's parameters from the final joint coefficients."""
    start = 0
    for s in steps:
        n = s.effect.n_terms
        s.parameters = s.effect.describe(final.coef[start : start + n])
        start += n


def diagnose_arrays(
    time_s: np.ndarray, motor_deg: np.ndarray, load_deg: np.ndarray, ratio: float, torque_Nm: np.ndarray | None = None, **options: Any
) -> Diagnosis:
    """:func:`diagnose` on plain arrays (torque optional)."""
    n = len(time_s)
    torque = np.full(n, np.nan) if torque_Nm is None else np.asarray(torque_Nm, dtype=float)
    chunk = SampleChunk(np.asarray(time_s, float), np.asarray(motor_deg, float), np.asarray(load_deg, float), torque, np.zeros(n, bool))
    return diagnose(chunk, ratio, **options)

"""One round of :func:`.loop.diagnose`: detect the candidates on the residual, refit them, choose one.

Every effect of the library and every generic term is scored on the current fit's residual
(:mod:`._scoring`); the two named effects that explain most and the best generic term are refitted
jointly with the backlash and the terms already in (:class:`._refits.RoundRefits`). The named effect is
kept unless the generic term leaves clearly less (``label_ratio``); a candidate whose refit gives a term a
figure no drive can have, or does not realise ``min_gain``, is refused. On a screened record the choice
is detected again, configured and fitted on every sample (:meth:`SearchRound.settled`).
Angles in degrees on the load side, time in seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ._fit_view import FitView, detection_data, scored_columns
from ._loop_record import LoopRecord
from ._refits import RoundRefits
from ._scoring import Detection, DetectionData
from ._term_columns import TermColumns
from .diagnosis import AddedTerm
from .effects import LIBRARY
from .generic_terms import GENERIC
from .joint import JointFit

#: the runner-up named effect is refitted too when its linear gain is at least this share of the best one's
RUNNER_UP_SHARE = 0.8


@dataclass(frozen=True)
class SelectionRules:
    """What a term must show to be added (the parameters of :func:`.loop.diagnose` of the same names)."""

    bic_threshold: float
    min_gain: float
    label_ratio: float


@dataclass(frozen=True)
class Choice:
    """The candidate a round chose, its joint refit, and the named effects refitted beside it."""

    #: ``"effect"`` (named) or ``"unexplained"`` (a generic term)
    kind: str
    detection: Detection
    fit: JointFit
    #: every named candidate's detection and joint refit, the chosen one's included
    named_refits: list[tuple[Detection, JointFit]]


@dataclass
class SearchRound:
    """One round, from the fit ``refits.current`` with the terms ``refits.done`` in: the significant
    candidates ``named`` (the one that explains most first) and ``generic`` (the best generic term).
    ``refused`` is the loop's set of effect classes it no longer tries; a round adds to it."""

    record: LoopRecord
    rules: SelectionRules
    refused: set[type]
    refits: RoundRefits
    named: list[Detection]
    generic: Detection | None

    @classmethod
    def detect(
        cls, record: LoopRecord, current: JointFit, steps: list[AddedTerm], refused: set[type], rules: SelectionRules
    ) -> SearchRound:
        """The candidates of the round after ``steps`` on the fit ``current`` (scored on the screen's cycles)."""
        taken = {type(s.effect) for s in steps} | refused
        r = record
        view = FitView.of(r.uc, current.params)  # the round's model: its detectors' and its confirmation's
        done = [s.effect for s in steps]
        data = detection_data(
            r.u_deg,
            r.time_s,
            r.torque_Nm,
            r.uc,
            current,
            done,
            r.ratio,
            r.period_s,
            r.screen,
            r.built,
            r.cache,
            view,
            noise=r.noise,
        )
        named = significant([c.detect(data) for c in LIBRARY if c not in taken], rules)
        named = [without_columns(d, r.built) for d in named]
        generic = significant([c.detect(data) for c in GENERIC if c not in taken], rules)
        return cls(r, rules, refused, RoundRefits(r, current, view, done, data), named, generic[0] if generic else None)

    @property
    def found_any(self) -> bool:
        """True when some candidate is significant."""
        return bool(self.named) or self.generic is not None

    def physical(self, found: Detection, fit: JointFit) -> bool:
        """False (and the candidate refused) where its refit gives a term a figure no drive can have."""
        r = self.record
        if all_physical([*self.refits.done, found.effect], fit.coef, r.u_deg, r.time_s, r.noise.floor_deg):
            return True
        self.refused.add(type(found.effect))
        return False

    def chosen(self) -> Choice | None:
        """The two named effects that explain most are both refitted: the better joint fit is named; a named
        effect must do about as well as a flexible generic term in the joint refit. None: every refit refused
        as unphysical."""
        named: Detection | None = None
        fit_named: JointFit | None = None
        named_refits: list[tuple[Detection, JointFit]] = []
        for candidate in self.named[:2]:
            if fit_named is not None and candidate.score.gain < RUNNER_UP_SHARE * self.named[0].score.gain:
                break
            tried = self.refits.candidate(candidate)
            if not self.physical(*tried):
                continue
            named_refits.append(tried)
            if fit_named is None or named_refits[-1][1].rms_deg < fit_named.rms_deg:
                named, fit_named = named_refits[-1]
        generic, fit_generic = self.generic, None
        if generic is not None:
            generic, fit_generic = self.refits.candidate(generic)
            if not self.physical(generic, fit_generic):
                generic = fit_generic = None
        if (
            named is not None
            and fit_named is not None
            and (fit_generic is None or fit_named.rms_deg**2 <= self.rules.label_ratio * fit_generic.rms_deg**2)
        ):
            return Choice("effect", named, fit_named, named_refits)
        if generic is not None and fit_generic is not None:
            return Choice("unexplained", generic, fit_generic, named_refits)
        return None

    def rivals(self, choice: Choice) -> tuple[str, ...]:
        """The named effects refitted about as well as the chosen one and explaining the same part of the
        residual (an unexplained choice has none)."""
        if choice.kind != "effect":
            return ()
        within = self.rules.label_ratio * choice.fit.rms_deg**2
        close = [d for d, f in choice.named_refits if d is not choice.detection and f.rms_deg**2 <= within]
        found = inseparable_rivals(self.refits.data, choice.detection, close, self.rules.min_gain, self.record.built)
        return (*choice.detection.rivals, *found)

    def settled(self, choice: Choice) -> tuple[list[Any], Detection, JointFit, DetectionData] | None:
        """The terms with the choice in, its detection, their joint fit on every sample and the detection data
        over every sample. Without a screen, the settings of the terms already in are retuned with the new
        one in (the compliance's torque average). Chosen on the screen: configured, evidenced and fitted on
        every sample, as without the screen, every setting walked there (the new term's own first, as
        :meth:`._refits.RoundRefits.candidate` does, then those of the terms already in). None: the whole
        record does not bear it out."""
        refits, done, r = self.refits, self.refits.done, self.record
        if not r.screen.screened:
            terms, fit = refits.walked([*done, choice.detection.effect], choice.fit, range(len(done)))
            return terms, choice.detection, fit, refits.data
        whole = detection_data(
            r.u_deg,
            r.time_s,
            r.torque_Nm,
            r.uc,
            refits.current,
            done,
            r.ratio,
            r.period_s,
            r.folds,
            r.built,
            r.cache,
            refits.view,
            noise=r.noise,
        )
        confirmed = confirmed_on_every_sample(choice.detection, whole, r.built, self.rules)
        if confirmed is None:
            return None
        terms = [*done, confirmed.effect]
        start = refits.refit(terms, every_sample=True, start=choice.fit)
        terms, fit = refits.walked(terms, start, [len(done), *range(len(done))], every_sample=True)
        if terms[-1] is confirmed.effect:
            return terms, confirmed, fit, whole
        return terms, replace(terms[-1].detection(whole), rivals=confirmed.rivals), fit, whole

    def next_term(self, number: int) -> tuple[list[Any], JointFit, AddedTerm] | None:
        """The terms with the round's choice in (the settings of those already in as they are now fitted),
        their joint fit on every sample, and the choice as the ``number``-th term added. None: every
        candidate refused (the refused ones are in ``refused``: the loop tries the others)."""
        choice = self.chosen()
        if choice is None:  # every refit refused as unphysical: try the others
            return None
        current, min_gain = self.refits.current, self.rules.min_gain
        if choice.fit.rms_deg**2 > (1.0 - min_gain) * current.rms_deg**2:
            self.refused.add(type(choice.detection.effect))  # the refit does not realise the gain: try the others
            return None
        rivals = self.rivals(choice)
        settled = self.settled(choice)
        if settled is None:
            self.refused.add(type(choice.detection.effect))  # the whole record does not bear it out: try the others
            return None
        terms, chosen, fit, every_sample = settled
        return (
            terms,
            fit,
            AddedTerm(
                "not_separable" if rivals else choice.kind,
                chosen.effect,
                chosen,
                current.rms_deg,
                fit.rms_deg,
                current.params.play,
                fit.params.play,
                fit.play_inflation,
                fit.play_std_deg,
                fit.play_held,
                number,
                residual_after_deg=fit.residual_deg,
                heldout_split=self.record.folds.as_dict(),
                rivals=rivals,
                scored_on=(current, tuple(self.refits.done)),
                scored_data=every_sample if hasattr(chosen.effect, "neighbours") else None,
            ),
        )


def significant(found: list[Detection | None], rules: SelectionRules) -> list[Detection]:
    """The significant detections, the one that explains most first."""
    ok = [d for d in found if d is not None and d.score.significant(rules.bic_threshold, rules.min_gain)]
    return sorted(ok, key=lambda d: -d.score.gain)


def inseparable_rivals(
    data: DetectionData, chosen: Detection, others: list[Detection], min_gain: float, built: TermColumns | None = None
) -> tuple[str, ...]:
    """Named effects that explain the same part of the residual as the chosen one: neither
    removes ``min_gain`` of the residual's mean square once the other is in. ``built``: the loop's
    term columns of this record (else built here)."""
    built = TermColumns(data.u_deg, data.time_s, data.torque_Nm) if built is None else built
    xa = scored_columns(data, chosen.effect, built)
    names = []
    for d in others:
        if d is chosen:
            continue
        xb = scored_columns(data, d.effect, built)
        chosen_beyond = data.with_nuisance(xb).score(False, xa).gain  # the chosen one's gain with the other in
        if chosen_beyond < min_gain and data.with_nuisance(xa).score(False, xb).gain < min_gain:
            names.append(str(getattr(d.effect, "name", "")))
    return tuple(names)


def all_physical(terms: Sequence[Any], coef: np.ndarray, u: np.ndarray, t: np.ndarray, tolerance_deg: float) -> bool:
    """True unless the joint coefficients ``coef`` (the terms' side by side) give a term with ``is_physical``
    (the dead band's creep) a figure no drive can have, beyond ``tolerance_deg`` (the noise floor); ``u`` and
    ``t``: the record's referred motor angle (deg) and time (s)."""
    ends = np.cumsum([0, *(e.n_terms for e in terms)])
    checked = [(e, a, b) for e, a, b in zip(terms, ends[:-1], ends[1:]) if hasattr(e, "is_physical")]
    return all(e.is_physical(coef[a:b], u, t, tolerance_deg) for e, a, b in checked)


def confirmed_on_every_sample(
    chosen: Detection, data: DetectionData, built: TermColumns, rules: SelectionRules
) -> Detection | None:
    """A term chosen on a screen of the record, detected again on ``data``, every sample of it (the
    round's residual, the terms it had): its configuration (the harmonic orders, the dead band's
    parts, ...) and its evidence as without the screen. A term with a setting walked in the refit
    (``neighbours``, the compliance's torque average) is scored with its setting from the screen
    (the caller walks it again on every sample). None when the whole record does not find it significant."""
    effect: Any = chosen.effect
    again = effect.detection(data) if hasattr(effect, "neighbours") else type(effect).detect(data)
    if again is None or not again.score.significant(rules.bic_threshold, rules.min_gain):
        return None
    return replace(without_columns(again, built), rivals=chosen.rivals)


def without_columns(found: Detection, built: TermColumns) -> Detection:
    """``found`` without its columns, which go to ``built`` for the fits (a detector that formed its
    effect's columns on every sample hands them on: :attr:`._scoring.Detection.columns`)."""
    if found.columns is None:
        return found
    built.put(found.effect, found.columns, found.nonzero_rows)
    return replace(found, columns=None, nonzero_rows=None)

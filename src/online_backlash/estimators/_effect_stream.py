"""The effects of a recursive estimator, fed with its stream: their columns, and what restores them.

An effect keeps a stream history between calls (:mod:`online_backlash.effect_terms`). To save
an estimator and continue bit for bit, :class:`EffectStream` keeps, since the effects' last
reset, the first sample and the last ``history`` ones (the effects' own promise, see
:func:`~online_backlash.effect_terms.stream_history`): replaying them through fresh effects
restores their history exactly. Units: degrees, seconds, N m.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..effect_terms import EffectTerms, effect_from_dict, effect_to_dict, stream_history
from ..errors import InvalidParameterError


def check_effects(effects: Sequence[EffectTerms] | None) -> list[EffectTerms]:
    """The effects as a list, each following :class:`~online_backlash.effect_terms.EffectTerms`."""
    out = list(effects or [])
    for eff in out:
        if not isinstance(eff, EffectTerms):
            raise InvalidParameterError(
                "effects must follow online_backlash.effect_terms.EffectTerms (name, n_terms, terms, reset), "
                f"got {eff!r}"
            )
    return out


def effects_from_records(records: list[Any], effects: Sequence[EffectTerms] | None) -> list[EffectTerms]:
    """Effects for a saved state: ``effects`` if given (their names must match), else rebuilt by
    name from the records (:func:`~online_backlash.effect_terms.effect_from_dict`).

    A record is ``{"name", "params"}``, or a bare name (state format 2).
    """
    names = [r if isinstance(r, str) else r["name"] for r in records]
    if effects is not None and len(effects):
        given = list(effects)
        if [e.name for e in given] != names:
            raise InvalidParameterError(
                f"the saved state was learned with effects {names}; pass effects with these names"
            )
        return given
    if any(isinstance(r, str) for r in records):
        raise InvalidParameterError(
            f"the saved state names its effects {names} without their parameters; pass effects with these names"
        )
    return [effect_from_dict(r) for r in records]


def _json_floats(a: np.ndarray) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in a]  # NaN (no torque) is not JSON


def _from_json(values: list[float | None]) -> np.ndarray:
    return np.array([math.nan if v is None else v for v in values], dtype=float)


class EffectStream:
    """Effects fed with one stream of samples (``u`` deg, ``time`` s, ``torque`` N m).

    Parameters
    ----------
    effects : list of EffectTerms
    """

    def __init__(self, effects: Sequence[EffectTerms]) -> None:
        self.effects = list(effects)
        hist = [stream_history(e) for e in self.effects]
        known = [h for h in hist if h is not None]
        #: samples kept to restore the effects (None: an effect does not say, it restarts on restore)
        self.keep: int | None = max(known, default=0) if len(known) == len(hist) else None
        self._first = np.empty((3, 0))
        self._recent = np.empty((3, 0))
        self._count = 0

    @property
    def n_terms(self) -> int:
        """Regressor columns of all the effects."""
        return sum(int(e.n_terms) for e in self.effects)

    def reset(self) -> None:
        """Forget the stream (start, or a gap)."""
        for e in self.effects:
            e.reset()
        self._first = np.empty((3, 0))
        self._recent = np.empty((3, 0))
        self._count = 0

    def terms(
        self, u: np.ndarray, t: np.ndarray, q: np.ndarray, effects: Sequence[EffectTerms] | None = None
    ) -> np.ndarray:
        """Columns ``(len(u), n_terms)`` of ``effects`` (default: the stream's own) for these samples,
        without recording them as the stream's (the warm start's batch fit, predictions on copies)."""
        if u.size == 0:
            return np.empty((0, self.n_terms))
        cols = [
            np.asarray(e.terms(u, t, q), dtype=float).reshape(u.size, -1)
            for e in (self.effects if effects is None else effects)
        ]
        return np.concatenate(cols, axis=1) if cols else np.empty((u.size, 0))

    def feed(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Columns for the stream's next samples; records what restores the effects."""
        rows = self.terms(u, t, q)
        if self.keep is not None and u.size:
            block = np.vstack((u, t, q))
            if self._count == 0:
                self._first = block[:, :1].copy()
            self._count += u.size
            kept = np.hstack((self._recent, block)) if self._recent.size else block
            self._recent = kept[:, kept.shape[1] - min(self.keep, kept.shape[1]) :].copy()
        return rows

    def state_dict(self) -> dict[str, Any]:
        """The effects by name and parameters, and the samples that restore their history (JSON types)."""
        d: dict[str, Any] = {"effects": [effect_to_dict(e) for e in self.effects], "count": self._count}
        d["first"] = [_json_floats(row) for row in self._first]
        d["recent"] = [_json_floats(row) for row in self._recent]
        return d

    def restore(self, d: dict[str, Any]) -> None:
        """Reset the effects and replay the saved samples through them."""
        self.reset()
        if self.keep is None or not d.get("count"):
            return
        first = np.array([_from_json(row) for row in d["first"]]).reshape(3, -1)
        recent = np.array([_from_json(row) for row in d["recent"]]).reshape(3, -1)
        if int(d["count"]) > recent.shape[1]:  # the first sample is not among the recent ones
            self.feed(*first)
        if recent.shape[1]:
            self.feed(*recent)
        self._count = int(d["count"])

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

Effects are saved by name: :data:`EFFECTS` maps a name to its class (the library's, listed once where they
are declared, in :data:`online_backlash.diagnostics.effects.LIBRARY`, and any added by :func:`register_effect`), and
:func:`effect_to_dict` / :func:`effect_from_dict` turn an effect into JSON and back (its
constructor arguments; the stream history is the estimator's to restore, see
:meth:`~online_backlash.estimators.BacklashRLS.state_dict`).
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Iterator, MutableMapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .errors import InvalidParameterError


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


def stream_history(effect: EffectTerms) -> int | None:
    """Samples of the past an effect's rows depend on (its ``history`` attribute), or None if it
    does not say.

    An effect that declares ``history`` promises that its stream state after a run of samples
    since its last reset is fixed by the first of them and the last ``history`` ones (as for
    :class:`~online_backlash.diagnostics.effects.EffectBase`: a causal window and the first time
    seen); an estimator saves those and replays them to restore the effect exactly.
    """
    h = getattr(effect, "history", None)
    return None if h is None else int(h)


#: The module that declares the library's effects: its ``LIBRARY`` lists them. It is imported on the first look-up by
#: name, not here, so that importing this module stays light and the estimators do not import the diagnostics.
LIBRARY_MODULE = "online_backlash.diagnostics.effects"


class EffectRegistry(MutableMapping[str, type]):
    """Effect classes by their ``name``: the library's (``LIBRARY`` of :data:`LIBRARY_MODULE`, read on first use)
    and those added with :func:`register_effect`, which take precedence over a library effect of the same name."""

    def __init__(self, library_module: str) -> None:
        self._library_module = library_module
        self._added: dict[str, type] = {}
        self._classes: dict[str, type] | None = None

    def _all(self) -> dict[str, type]:
        if self._classes is None:
            library = importlib.import_module(self._library_module).LIBRARY
            self._classes = {cls.name: cls for cls in library}
        return {**self._classes, **self._added}

    def __getitem__(self, name: str) -> type:
        return self._all()[name]

    def __setitem__(self, name: str, cls: type) -> None:
        self._added[name] = cls

    def __delitem__(self, name: str) -> None:
        del self._added[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


#: The effects a saved estimator can name. :func:`register_effect` adds others.
EFFECTS = EffectRegistry(LIBRARY_MODULE)


def register_effect(cls: type, name: str | None = None) -> type:
    """Register an effect class under ``name`` (default: its ``name`` attribute); returns ``cls``.

    Usable as a class decorator. A saved estimator state names its effects; :func:`effect_from_dict`
    finds the class here.
    """
    EFFECTS[name or cls.name] = cls  # type: ignore[attr-defined]
    return cls


def effect_class(name: str) -> type:
    """The effect class registered under ``name``; InvalidParameterError if there is none."""
    entry = EFFECTS.get(name)
    if entry is None:
        raise InvalidParameterError(f"no effect named {name!r} is registered; known: {sorted(EFFECTS)}")
    return entry


def effect_to_dict(effect: EffectTerms) -> dict[str, Any]:
    """``{"name", "params"}`` of an effect, JSON-serialisable: its name and constructor arguments.

    The effect must expose ``get_params()`` (as :class:`~online_backlash.diagnostics.effects.EffectBase`
    does; without it ``params`` is None and the effect can only be passed back by the caller);
    tuples are saved as lists.
    """
    get_params = getattr(effect, "get_params", None)
    params = None if get_params is None else json.loads(json.dumps(get_params()))
    return {"name": effect.name, "params": params}


def effect_from_dict(d: dict[str, Any]) -> EffectTerms:
    """The effect saved by :func:`effect_to_dict`: the registered class built with the saved
    arguments (lists become tuples again), with no stream history."""
    if d.get("params") is None:
        raise InvalidParameterError(
            f"effect {d.get('name')!r} was saved without its parameters (no get_params()); pass it explicitly"
        )
    params = {k: tuple(v) if isinstance(v, list) else v for k, v in d["params"].items()}
    effect = effect_class(d["name"])(**params)
    if not isinstance(effect, EffectTerms):
        raise InvalidParameterError(f"the class registered as {d['name']!r} does not follow EffectTerms")
    return effect

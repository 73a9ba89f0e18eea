"""The columns of the terms the loop has taken, built once per record.

Every round of :func:`.loop.diagnose` refits the backlash with all the terms added so far
(:func:`.joint.fit_guarded`), hands them to the next round's detectors as nuisance columns, and at
the end holds each one out given the others: the same term's columns over the same record are
needed many times. A term's columns depend on the record only (``u``, ``t``, ``q``, a fresh
stream: :meth:`EffectBase.terms` of a clone, made from the term's parameters), so :class:`TermColumns`
builds them once per term, by its parameters (its ``repr``: the walk of a setting and the next round
make new objects of settings already built), and serves the same (read-only) array after that.
What depends on the current backlash fit (gating by the engaged samples of eq. 5-6, holding through
the dead band, a term built on the model's output such as the delay) is applied by the caller on
every use.

Units: those of the term's columns (degrees of load angle per unit coefficient).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .joint import Support

#: most memory the columns of terms not taken keep from one round to the next (bytes): the 10-minute bench log's
#: candidates and walked settings (about 60 MB) all fit; a 60-minute log keeps some of them
SPARE_BYTES = 128 * 2**20


class TermColumns:
    """``get(effect)``: ``effect.clone().terms(u_deg, time_s, torque_Nm)``, built once per effect's parameters
    (:func:`columns_key`).

    Parameters
    ----------
    u_deg, time_s, torque_Nm : arrays
        The referred motor angle (deg), time (s) and torque (N m, NaN where none) of the record.
    """

    def __init__(self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray) -> None:
        self.u_deg, self.time_s, self.torque_Nm = u_deg, time_s, torque_Nm
        # keyed by the effect's parameters (columns_key)
        self._built: dict[str, np.ndarray] = {}
        # keyed so too, checked against the columns they were found in (kept in ``_built``)
        self._supports: dict[str, tuple[np.ndarray, Support | None]] = {}

    def put(self, effect: Any, columns: np.ndarray, nonzero_rows: np.ndarray | None = None) -> None:
        """Keep ``columns`` as the effect's (formed elsewhere: they must be its ``terms`` on a fresh
        stream over the record, ``(n, effect.n_terms)``), read-only from now on; ``nonzero_rows``: their
        rows with a value other than zero (increasing), when known (else :meth:`support` finds them)."""
        if columns.shape != (self.u_deg.size, effect.n_terms):
            raise ValueError(
                f"columns of shape {columns.shape} for {effect!r}, expected {(self.u_deg.size, effect.n_terms)}"
            )
        columns.flags.writeable = False
        key = columns_key(effect)
        self._built[key] = columns
        if nonzero_rows is not None:
            self._supports[key] = (columns, Support.of(columns, rows=nonzero_rows))

    def get(self, effect: Any) -> np.ndarray:
        """The effect's columns ``(n, effect.n_terms)`` over the whole record (read-only); an effect that
        notes the rows its columns are not zero on as it forms them (``columns_and_support_at``, the dead
        band's motion) hands them on too."""
        hit = self._built.get(columns_key(effect))
        if hit is not None:
            return hit
        if hasattr(effect, "columns_and_support_at"):
            cols, nonzero = effect.columns_and_support_at(self.u_deg, self.time_s, self.torque_Nm, None)
            self.put(effect, cols, nonzero)
            return cols
        cols = np.asarray(effect.clone().terms(self.u_deg, self.time_s, self.torque_Nm), dtype=float)
        self.put(effect, cols)
        return cols

    def keep_only(self, effects: Sequence[Any], spare_bytes: int = SPARE_BYTES) -> None:
        """Forget the columns (and supports) of every effect but ``effects`` (the terms taken), and of the others
        (the candidates and the walked settings) all but the last built that fit in ``spare_bytes``: the next round
        refits the candidates it finds again and walks the settings near the taken ones, often the same, but on a
        long record they add up to gigabytes."""
        kept = {columns_key(e) for e in effects}
        spare = spare_bytes
        for key, columns in reversed(self._built.items()):  # the last built first
            if key not in kept and columns.nbytes <= spare:
                kept.add(key)
                spare -= columns.nbytes
        self._built = {k: v for k, v in self._built.items() if k in kept}
        self._supports = {k: v for k, v in self._supports.items() if k in self._built}

    def support(self, effect: Any) -> Support | None:
        """The :class:`.joint.Support` of the effect's columns (:meth:`get`): the samples outside which
        they are zero, when that is a small share of the record (found once per effect's parameters)."""
        cols, key = self.get(effect), columns_key(effect)
        hit = self._supports.get(key)
        if hit is not None and hit[0] is cols:
            return hit[1]
        found = Support.of(cols)
        self._supports[key] = (cols, found)
        return found


def columns_key(effect: Any) -> str:
    """What a term's columns over a record are a function of: its class and its parameters (its ``repr``, the
    constructor's arguments with floats to the last bit: :meth:`._effect_base.EffectBase.__repr__`)."""
    return repr(effect)

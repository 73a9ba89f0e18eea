"""How much of a residual a set of regressor columns explains, with an information criterion.

The residual of a fitted backlash model is autocorrelated wherever something is missing, so
counting every sample as independent evidence would make everything look significant. The
criterion below therefore uses an effective sample size from the lag-1 autocorrelation
``rho`` of what is left after the columns are fitted, ``n_eff = n (1 - rho) / (1 + rho)``
(the AR(1) variance-inflation rule), in a Bayesian information criterion:

    delta_bic = n_eff ln(RSS_after / RSS_before) + q ln(n_eff)

``delta_bic < 0`` favours the columns; :data:`BIC_THRESHOLD` ("very strong" evidence on the
Kass-Raftery scale) keeps false alarms rare, :data:`MIN_GAIN` asks the columns to remove a
share of the residual's mean square that matters, and :data:`MIN_OWN_SHARE` refuses columns
that are nearly collinear with what the model already has.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

#: delta_bic must fall below this for a term to count as detected
BIC_THRESHOLD = -10.0
#: and the term must remove at least this share of the residual's mean square
MIN_GAIN = 0.05
#: and every column must keep at least this share of its variance once the terms already in
#: the model are projected out; below it the term is nearly collinear with them and would only
#: trade amplitude with them (collinearity with the play is the joint fit's guard)
MIN_OWN_SHARE = 0.1


@dataclass(frozen=True)
class Score:
    """The fit of some columns to a residual (degrees).

    Attributes
    ----------
    rss_before, rss_after : float
        Residual sum of squares without and with the columns (plus an intercept), deg^2.
    n_eff : float
        Effective number of independent samples.
    delta_bic : float
        Change of the information criterion (negative: the columns are worth their parameters).
    coef : array
        Least-squares coefficients of the columns (the intercept dropped).
    own_share : float
        Smallest share of a column's variance left after projecting out the nuisance columns.
    """

    n_terms: int
    rss_before: float
    rss_after: float
    n_eff: float
    delta_bic: float
    coef: np.ndarray
    own_share: float = 1.0

    @property
    def gain(self) -> float:
        """Share of the residual's sum of squares the columns remove, 0..1."""
        return 1.0 - self.rss_after / self.rss_before if self.rss_before > 0 else 0.0

    def significant(self, bic_threshold: float = BIC_THRESHOLD, min_gain: float = MIN_GAIN) -> bool:
        """True when the criterion, the size test and the collinearity test all pass."""
        return self.delta_bic < bic_threshold and self.gain >= min_gain and self.own_share >= MIN_OWN_SHARE


def effective_samples(residual: np.ndarray) -> float:
    """``n (1 - rho) / (1 + rho)`` with ``rho`` the lag-1 autocorrelation (clipped to [0, 0.9999])."""
    r = residual - residual.mean()
    denom = float(np.dot(r, r))
    rho = float(np.dot(r[1:], r[:-1]) / denom) if denom > 0 else 0.0
    rho = min(max(rho, 0.0), 0.9999)
    return max(r.size * (1.0 - rho) / (1.0 + rho), 2.0)


def score_columns(residual: np.ndarray, columns: np.ndarray, nuisance: np.ndarray | None = None) -> Score:
    """Least squares of ``residual`` on ``columns`` (n x q) plus ``nuisance`` columns, and its criterion.

    ``nuisance`` (default: an intercept) are directions the model can move anyway, here the
    sensitivities of the backlash output to its four parameters: a term is scored on what it
    explains beyond a shift of the backlash parameters, and can take back what the base fit
    let the play absorb.
    """
    base = np.ones((residual.size, 1)) if nuisance is None else nuisance
    qb = np.linalg.qr(base)[0]
    return _score_projected(residual, columns, qb, qb)


def _score_projected(residual: np.ndarray, columns: np.ndarray, qb: np.ndarray, qt: np.ndarray) -> Score:
    """:func:`score_columns` with the nuisance columns given by an orthonormal basis ``qb``;
    the own share is measured against the basis ``qt`` (a constant and the terms already added)."""
    columns = np.asarray(columns, dtype=float).reshape(residual.size, -1)
    q = columns.shape[1]
    r0 = residual - qb @ (qb.T @ residual)
    xp = columns - qb @ (qb.T @ columns)
    xt = columns - qt @ (qt.T @ columns)
    centred = columns - columns.mean(axis=0)
    total = np.einsum("ij,ij->j", centred, centred)
    own = float(np.min(np.einsum("ij,ij->j", xt, xt) / np.maximum(total, 1e-300))) if q else 1.0
    coef, *_ = np.linalg.lstsq(xp, r0, rcond=None)
    left = r0 - xp @ coef
    rss0, rss1 = float(np.dot(r0, r0)), float(np.dot(left, left))
    n_eff = effective_samples(left)
    if rss0 <= 0:
        return Score(q, rss0, rss1, n_eff, 0.0, coef, own)
    delta = n_eff * np.log(max(rss1, 1e-300) / rss0) + q * np.log(n_eff)
    return Score(q, rss0, rss1, n_eff, float(delta), coef, own)


@dataclass(frozen=True)
class DetectionData:
    """What an effect's detector sees: the record and the current simulation residual.

    Angles in degrees (``u_deg`` is the motor angle referred to the load side), time in
    seconds, torque in N m (NaN where the log has none).
    """

    u_deg: np.ndarray
    time_s: np.ndarray
    torque_Nm: np.ndarray
    residual_deg: np.ndarray
    ratio: float
    sample_period_s: float
    nuisance: np.ndarray | None = None
    engaged_index: np.ndarray | None = None
    #: leading nuisance columns that are the backlash's own directions, a constant first (not
    #: counted in ``own_share``); the nuisance columns must include a constant
    n_backlash: int = 0
    #: orthonormal bases (QR) of all nuisance columns and of the non-backlash ones, set in __post_init__
    base_basis: np.ndarray = field(init=False, repr=False)
    terms_basis: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        ones = np.ones((self.residual_deg.size, 1))
        base = ones if self.nuisance is None else self.nuisance
        if self.nuisance is None:
            terms = ones
        elif self.n_backlash:  # the backlash block starts with the constant: keep it
            terms = np.column_stack((ones, self.nuisance[:, self.n_backlash :]))
        else:
            terms = self.nuisance
        object.__setattr__(self, "base_basis", np.linalg.qr(base)[0])
        object.__setattr__(self, "terms_basis", np.linalg.qr(terms)[0])

    def hold(self, columns: np.ndarray) -> np.ndarray:
        """Input-side columns held through the dead band of the current model (see :mod:`.joint`)."""
        columns = np.asarray(columns, dtype=float).reshape(self.residual_deg.size, -1)
        return columns if self.engaged_index is None else columns[self.engaged_index]

    def score(self, input_side: bool, columns: np.ndarray) -> Score:
        """:func:`score_columns` of ``columns`` on this residual beyond the nuisance columns
        (held through the dead band when ``input_side``)."""
        return _score_projected(self.residual_deg, self.hold(columns) if input_side else columns, self.base_basis, self.terms_basis)

    def with_nuisance(self, columns: np.ndarray) -> DetectionData:
        """The same data with ``columns`` added to the nuisance columns."""
        base = np.ones((self.residual_deg.size, 1)) if self.nuisance is None else self.nuisance
        return replace(self, nuisance=np.column_stack((base, columns)))


@dataclass(frozen=True)
class Detection:
    """An effect configured to fit the residual, its score, and a sentence of evidence."""

    effect: object
    score: Score
    evidence: str


def best_detection(candidates: list[Detection]) -> Detection | None:
    """The candidate with the lowest information criterion, or None for an empty list."""
    return min(candidates, key=lambda d: d.score.delta_bic, default=None)

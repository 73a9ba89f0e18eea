"""The backlash model of Vörös (2010) and its cascade with a linear system.

Equation numbers refer to J. Vörös, "Modeling and identification of systems with backlash",
Automatica 46 (2010) 369-374 (restated in ``PAPER.md``).

Units: ``u`` (input, the motor angle referred to the load side) and ``x`` (backlash output,
the load angle) share one unit, degrees in this package; slopes are dimensionless and the
dead-band parameters ``c_left``, ``c_right`` are in input units. Time is the sample index.

Examples
--------
>>> import numpy as np
>>> from online_backlash.model import BacklashParams, simulate_backlash, simulate_switching
>>> p = BacklashParams(m_left=1.0, c_left=0.2, m_right=1.0, c_right=0.3)
>>> u = np.array([0.0, 0.5, 1.0, 0.9, 0.6, 0.0])
>>> simulate_backlash(u, p)
array([0. , 0.2, 0.7, 0.7, 0.7, 0.2])
>>> bool(np.array_equal(simulate_backlash(u, p), simulate_switching(u, p)[0]))
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .errors import InvalidParameterError


@dataclass(frozen=True)
class BacklashParams:
    """The four parameters of eq. (1): slopes (dimensionless) and dead-band widths (input units).

    ``c_left + c_right`` is the total play in input units (:attr:`play`).
    """

    m_left: float
    c_left: float
    m_right: float
    c_right: float

    def __post_init__(self) -> None:
        for name in ("m_left", "c_left", "m_right", "c_right"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise InvalidParameterError(f"{name} must be finite, got {value!r}")
        if self.m_left == 0 or self.m_right == 0:
            raise InvalidParameterError("slopes m_left and m_right must be non-zero")
        if (self.m_left > 0) != (self.m_right > 0):
            raise InvalidParameterError(
                f"slopes must share one sign (eq. 1), got m_left={self.m_left}, m_right={self.m_right}"
            )

    @property
    def play(self) -> float:
        """Total dead band ``c_left + c_right``, input units."""
        return self.c_left + self.c_right

    @property
    def theta(self) -> np.ndarray:
        """The parameter vector of eq. (8): ``[mL, mL cL, mR, mR cR]``."""
        return np.array(
            [self.m_left, self.m_left * self.c_left, self.m_right, self.m_right * self.c_right]
        )

    @classmethod
    def from_theta(cls, theta: np.ndarray) -> "BacklashParams":
        """Eq. (9): ``mL = m1, cL = c1/m1, mR = m2, cR = c2/m2``."""
        m1, c1, m2, c2 = (float(v) for v in theta[:4])
        if m1 == 0 or m2 == 0:
            raise InvalidParameterError(f"theta gives a zero slope: {theta[:4]!r}")
        return cls(m_left=m1, c_left=c1 / m1, m_right=m2, c_right=c2 / m2)


def heaviside_le0(s: np.ndarray | float) -> np.ndarray:
    """Eq. (4): ``h(s) = 1 if s <= 0 else 0``."""
    return (np.asarray(s) <= 0).astype(float)


def switching_functions(
    u: np.ndarray, x_prev: np.ndarray, params: BacklashParams
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (5)-(6) evaluated element-wise: ``f1`` (left line active) and ``f2`` (right line active).

    ``x_prev`` holds ``x(t-1)`` for every ``u(t)``. Written with the divisions by the slopes,
    so both hold for negative slopes too.
    """
    mL, cL, mR, cR = params.m_left, params.c_left, params.m_right, params.c_right
    f1 = heaviside_le0((mL * u + mL * cL - x_prev) / mL)
    f2 = heaviside_le0((x_prev - mR * u + mR * cR) / mR)
    return f1, f2


@njit(cache=True)
def _backlash_loop(u, mL, cL, mR, cR, x0):  # pragma: no cover - compiled
    n = u.shape[0]
    x = np.empty(n)
    prev = x0
    for t in range(n):
        zL = prev / mL - cL  # eq. (2)
        zR = prev / mR + cR  # eq. (3)
        # eq. (1), the lines written out as mL u + mL cL and mR u - mR cR
        if u[t] <= zL:
            prev = mL * u[t] + mL * cL
        elif u[t] >= zR:
            prev = mR * u[t] - mR * cR
        x[t] = prev
    return x


@njit(cache=True)
def _switching_loop(u, mL, cL, mR, cR, x0):  # pragma: no cover - compiled
    n = u.shape[0]
    x = np.empty(n)
    f1 = np.empty(n)
    f2 = np.empty(n)
    prev = x0
    for t in range(n):
        a = 1.0 if (mL * u[t] + mL * cL - prev) / mL <= 0 else 0.0  # eq. (5)
        b = 1.0 if (prev - mR * u[t] + mR * cR) / mR <= 0 else 0.0  # eq. (6)
        # eq. (7); when the dead band is empty (cL + cR < 0 is excluded) both can't be 1
        prev = mL * u[t] * a + mL * cL * a + mR * u[t] * b - mR * cR * b + prev * (1 - a) * (1 - b)
        x[t] = prev
        f1[t] = a
        f2[t] = b
    return x, f1, f2


@njit(cache=True)
def _backlash_varying_loop(u, mL, cL, mR, cR, x0):  # pragma: no cover - compiled
    n = u.shape[0]
    x = np.empty(n)
    prev = x0
    for t in range(n):
        if u[t] <= prev / mL - cL[t]:  # eq. (2) with cL(t)
            prev = mL * u[t] + mL * cL[t]
        elif u[t] >= prev / mR + cR[t]:  # eq. (3) with cR(t)
            prev = mR * u[t] - mR * cR[t]
        x[t] = prev
    return x


def simulate_backlash_varying(
    u: np.ndarray, m_left: float, c_left: np.ndarray, m_right: float, c_right: np.ndarray, x0: float = 0.0
) -> np.ndarray:
    """Eq. (1)-(3) with time-varying dead-band widths ``c_left[t]``, ``c_right[t]`` (wear).

    Slopes are constant; ``c_left`` and ``c_right`` are arrays as long as ``u`` (input units).
    """
    u = _as_input(u)
    cL = np.ascontiguousarray(c_left, dtype=float)
    cR = np.ascontiguousarray(c_right, dtype=float)
    if cL.shape != u.shape or cR.shape != u.shape:
        raise InvalidParameterError("c_left and c_right must be arrays as long as u")
    BacklashParams(m_left, 0.0, m_right, 0.0)  # validates the slopes
    return _backlash_varying_loop(u, float(m_left), cL, float(m_right), cR, float(x0))


def _as_input(u: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(u, dtype=float)
    if arr.ndim != 1:
        raise InvalidParameterError(f"u must be one-dimensional, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidParameterError("u contains non-finite values")
    return arr


def _check_band(params: BacklashParams) -> None:
    if params.c_left + params.c_right < 0:
        raise InvalidParameterError(
            f"the dead band c_left + c_right must be >= 0, got {params.c_left + params.c_right}"
        )


def simulate_backlash(u: np.ndarray, params: BacklashParams, x0: float = 0.0) -> np.ndarray:
    """Backlash output by the case form, eq. (1)-(3).

    Parameters
    ----------
    u : array, shape (n,)
        Input, input units (degrees here).
    params : BacklashParams
    x0 : float
        Output before the first sample, ``x(-1)``.

    Returns
    -------
    x : array, shape (n,)
    """
    _check_band(params)
    return _backlash_loop(_as_input(u), params.m_left, params.c_left, params.m_right, params.c_right, float(x0))


def simulate_switching(
    u: np.ndarray, params: BacklashParams, x0: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backlash output by the switching-function form, eq. (4)-(7).

    Returns ``(x, f1, f2)``; ``x`` equals :func:`simulate_backlash` exactly.
    """
    _check_band(params)
    return _switching_loop(_as_input(u), params.m_left, params.c_left, params.m_right, params.c_right, float(x0))


def linear_filter(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The linear block of eq. (15)-(17): ``y(t) = x(t-1) + sum_{i>=2} a_i x(t-i) - sum_j b_j y(t-j)``.

    ``a`` holds ``[a2, ..., am]`` (``a1 = 1``, the key-term separation of eq. 18) and ``b`` holds
    ``[b1, ..., bn]``. Samples before the start are zero.
    """
    from scipy.signal import lfilter

    num = np.concatenate(([0.0, 1.0], np.asarray(a, dtype=float)))
    den = np.concatenate(([1.0], np.asarray(b, dtype=float)))
    return lfilter(num, den, np.asarray(x, dtype=float))


def simulate_cascade(
    u: np.ndarray, params: BacklashParams, a: np.ndarray, b: np.ndarray, x0: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Input backlash followed by a linear system, eq. (15)-(18).

    Returns ``(y, x)``: the system output and the internal (unmeasured) backlash output.
    """
    x = simulate_backlash(u, params, x0)
    return linear_filter(x, a, b), x

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
        return np.array([self.m_left, self.m_left * self.c_left, self.m_right, self.m_right * self.c_right])

    def feasible(self) -> BacklashParams:
        """These parameters where the dead band is >= 0, else the nearest with a zero dead band (both
        widths moved by half the overlap): with a negative dead band the flanks of eq. (1) cross and
        the model is not defined, so a gearbox without play is estimated at the boundary, play 0."""
        if self.play >= 0:
            return self
        half = -0.5 * self.play
        return BacklashParams(self.m_left, self.c_left + half, self.m_right, self.c_right + half)

    @classmethod
    def from_theta(cls, theta: np.ndarray) -> BacklashParams:
        """Eq. (9): ``mL = m1, cL = c1/m1, mR = m2, cR = c2/m2``."""
        m1, c1, m2, c2 = (float(v) for v in theta[:4])
        if m1 == 0 or m2 == 0:
            raise InvalidParameterError(f"theta gives a zero slope: {theta[:4]!r}")
        return cls(m_left=m1, c_left=c1 / m1, m_right=m2, c_right=c2 / m2)


def heaviside_le0(s: np.ndarray | float) -> np.ndarray:
    """Eq. (4): ``h(s) = 1 if s <= 0 else 0``."""
    return (np.asarray(s) <= 0).astype(float)


def switching_functions(u: np.ndarray, x_prev: np.ndarray, params: BacklashParams) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (5)-(6) evaluated element-wise: ``f1`` (left line active) and ``f2`` (right line active).

    ``x_prev`` holds ``x(t-1)`` for every ``u(t)``. Computed in the first form of (5)-(6),
    ``f1 = h(u - zL)`` and ``f2 = h(zR - u)`` with ``zL``, ``zR`` of eq. (2)-(3): it holds for
    negative slopes too, and it takes bit-for-bit the decisions of eq. (1) (the second form,
    the same quantity divided by the slope, rounds differently on the boundary).
    """
    z_left = x_prev / params.m_left - params.c_left  # eq. (2)
    z_right = x_prev / params.m_right + params.c_right  # eq. (3)
    return heaviside_le0(u - z_left), heaviside_le0(z_right - u)


@njit(inline="always")
def sensitivity_step(u, prev, mL, cL, mR, cR, d0, d1, d2, d3):  # pragma: no cover - compiled
    """One sample of eq. (1)-(3) and its derivatives: ``(x(t), d x(t) / d [mL, cL, mR, cR])`` from the
    input ``u(t)``, ``prev = x(t-1)`` and ``d0 .. d3``, the derivatives of ``x(t-1)`` (compiled into the
    loops that call it)."""
    if u <= prev / mL - cL:  # eq. (1)-(2), left line: x = mL (u + cL)
        return mL * u + mL * cL, u + cL, mL, 0.0, 0.0
    if u >= prev / mR + cR:  # eq. (1), (3), right line: x = mR (u - cR)
        return mR * u - mR * cR, 0.0, 0.0, u - cR, -mR
    return prev, d0, d1, d2, d3  # inside the band x(t) = x(t-1): the derivatives carry over


@njit(cache=True)
def _backlash_loop(u, mL, cL, mR, cR, x0):  # pragma: no cover - compiled
    """Eq. (1)-(3) along ``u``; ``cL``, ``cR`` one value a sample (a play that varies) or one value for all."""
    n = u.shape[0]
    x = np.empty(n)
    prev = x0
    step = 1 if cL.shape[0] > 1 else 0  # the flanks' index moves with t, or stays at the one value
    for t in range(n):
        # eq. (1)-(3) with cL(t), cR(t); the derivatives unused
        prev = sensitivity_step(u[t], prev, mL, cL[t * step], mR, cR[t * step], 0.0, 0.0, 0.0, 0.0)[0]
        x[t] = prev
    return x


@njit(cache=True)
def switching_at(u, x_prev, mL, cL, mR, cR):  # pragma: no cover - compiled
    """Eq. (5)-(6) at one sample, compiled: ``(f1, f2)`` as :func:`switching_functions` evaluates them
    (``f1 = h(u - zL)``, ``f2 = h(zR - u)`` with ``zL``, ``zR`` of eq. 2-3 from ``x(t-1)``)."""
    return (1.0 if u - (x_prev / mL - cL) <= 0 else 0.0), (1.0 if (x_prev / mR + cR) - u <= 0 else 0.0)


@njit(inline="always")
def switching_step(u, last, prev, a, b, mL, cL, mR, cR):  # pragma: no cover - compiled
    """One sample of :func:`simulate_switching`: ``(x(t), f1(t), f2(t))`` from the input ``u(t)``, the one
    before it ``last``, ``prev = x(t-1)`` and ``a, b = f1(t-1), f2(t-1)`` (compiled into the loops that
    call it)."""
    if u != last:  # an input that has not moved keeps the switching functions (see simulate_switching)
        a, b = switching_at(u, prev, mL, cL, mR, cR)
    # eq. (7); a and b are never both 1 while the band is open (zL < zR, see simulate_switching).
    # Written out per case (the terms with a factor 0 drop out exactly, up to the sign of a zero)
    if a and not b:
        prev = mL * u + mL * cL
    elif b and not a:
        prev = mR * u - mR * cR
    elif a and b:
        prev = mL * u + mL * cL + mR * u - mR * cR
    return prev, a, b


@njit(cache=True)
def _switching_loop(u, mL, cL, mR, cR, x0, u_prev, a_prev, b_prev):  # pragma: no cover - compiled
    n = u.shape[0]
    x = np.empty(n)
    f1 = np.empty(n)
    f2 = np.empty(n)
    prev = x0
    last, a, b = u_prev, a_prev, b_prev
    for t in range(n):
        prev, a, b = switching_step(u[t], last, prev, a, b, mL, cL, mR, cR)
        x[t] = prev
        f1[t] = a
        f2[t] = b
        last = u[t]
    return x, f1, f2


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
    return _backlash_loop(u, float(m_left), cL, float(m_right), cR, float(x0))


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
    cL, cR = np.array([params.c_left], dtype=float), np.array([params.c_right], dtype=float)  # one value for all
    return _backlash_loop(_as_input(u), params.m_left, cL, params.m_right, cR, float(x0))


def simulate_switching(
    u: np.ndarray, params: BacklashParams, x0: float = 0.0, previous: tuple[float, float, float] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backlash output by the switching-function form, eq. (4)-(7).

    Returns ``(x, f1, f2)``; ``x`` equals :func:`simulate_backlash` exactly while the band is
    open, ``zL < zR`` in eq. (2)-(3): ``cL + cR > 0`` (the paper's ``cL, cR > 0``) and, with
    unequal slopes, ``|x| < (cL + cR) / |1/mL - 1/mR|``. Where ``zL >= zR`` both switching functions can fire
    and eq. (7) adds both lines (``tests/test_model.py`` shows a case with ``cL = cR = 0``).

    A sample whose input equals the one before keeps that sample's ``f1``, ``f2``: in exact
    arithmetic eq. (5)-(6) give the same values there (on the left line ``x(t-1) / mL - cL`` is
    ``u(t-1)`` itself, a tie that ``h(0) = 1`` decides as engaged; in the dead band nothing has
    changed), but the round trip of ``x`` through the line lands a unit in the last place either
    side of ``u``: on quantised encoder data (a motor that has not moved a count between samples)
    the engaged samples would flicker with the last bit of the parameters. ``x`` is the same
    either way (an engaged line at the same input gives the same output as holding it).
    ``previous`` is ``(u, f1, f2)`` of the sample before the first (a stream continued in
    pieces); None: the first sample is tested as it is.
    """
    _check_band(params)
    u_prev, f1_prev, f2_prev = (float("nan"), 0.0, 0.0) if previous is None else (float(v) for v in previous)
    return _switching_loop(
        _as_input(u), params.m_left, params.c_left, params.m_right, params.c_right, float(x0), u_prev, f1_prev, f2_prev
    )


@njit(cache=True, nogil=True)
def _sensitivity_loop(u, mL, cL, mR, cR, x0, x, dx):  # pragma: no cover - compiled
    """:func:`_sensitivity_spans` over the whole of ``u``, into ``x`` and ``dx`` (every row written)."""
    one = np.zeros(1, dtype=np.int64)
    _sensitivity_spans(u, mL, cL, mR, cR, one, one, np.full(1, u.shape[0], dtype=np.int64), np.full(1, x0), x, dx)


@njit(cache=True, nogil=True)
def _sensitivity_spans(u, mL, cL, mR, cR, starts, firsts, stops, x0s, x, dx):  # pragma: no cover - compiled
    """Eq. (1)-(3) and the derivatives run from ``starts[k]`` (output ``x0s[k]`` before it, derivatives
    0) to ``stops[k]``, for every span ``k``; the rows from ``firsts[k]`` on written to ``x``, ``dx``
    one span after the other."""
    at = 0
    for k in range(starts.size):
        prev = x0s[k]
        d0 = d1 = d2 = d3 = 0.0  # d x(t-1) / d [mL, cL, mR, cR]
        for t in range(starts[k], stops[k]):
            prev, d0, d1, d2, d3 = sensitivity_step(u[t], prev, mL, cL, mR, cR, d0, d1, d2, d3)
            if t >= firsts[k]:
                x[at] = prev
                dx[at, 0] = d0
                dx[at, 1] = d1
                dx[at, 2] = d2
                dx[at, 3] = d3
                at += 1


def backlash_sensitivity(
    u: np.ndarray, params: BacklashParams, x0: float = 0.0, out: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Backlash output, eq. (1)-(3), and its derivatives with respect to ``[mL, cL, mR, cR]``.

    The derivatives hold the switching pattern (which line, if any, is active at each sample)
    fixed: on the left line ``dx/d[mL, cL] = [u + cL, mL]``, on the right line
    ``dx/d[mR, cR] = [u - cR, -mR]``, and inside the dead band ``x(t) = x(t-1)`` carries the
    derivatives of the previous sample. The output is continuous in the parameters and piecewise
    smooth, so these are its derivatives wherever no sample sits exactly on a switching boundary:
    the Jacobian of a Gauss-Newton fit of the simulation (output) error. ``out``: contiguous arrays
    ``(n,)`` and ``(n, 4)`` to write them into (views of larger arrays, say), returned.

    Returns
    -------
    x : array, shape (n,)
        Equal to :func:`simulate_backlash`.
    dx : array, shape (n, 4)
        ``d x(t) / d [m_left, c_left, m_right, c_right]``.
    """
    _check_band(params)
    u = _as_input(u)
    x, dx = (np.empty(u.size), np.empty((u.size, 4))) if out is None else out
    if x.shape != u.shape or dx.shape != (u.size, 4) or not (x.flags.c_contiguous and dx.flags.c_contiguous):
        raise InvalidParameterError(
            f"out must be contiguous arrays of shapes {u.shape} and {(u.size, 4)}, got {x.shape} and {dx.shape}"
        )
    _sensitivity_loop(u, params.m_left, params.c_left, params.m_right, params.c_right, float(x0), x, dx)
    return x, dx


def backlash_sensitivity_spans(
    u: np.ndarray, params: BacklashParams, starts: np.ndarray, firsts: np.ndarray, stops: np.ndarray, x0s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`backlash_sensitivity` on pieces of ``u``: piece ``k`` run from sample ``starts[k]`` with
    the output ``x0s[k]`` before it (derivatives 0), its samples ``firsts[k] .. stops[k] - 1`` returned,
    the pieces one after the other. Once a flank is engaged, eq. (1)-(3) no longer depend on the
    output before (the play operator forgets its state), nor do the derivatives: started early
    enough before a flank engages, a piece is the whole record's simulation."""
    _check_band(params)
    starts, firsts, stops = (np.ascontiguousarray(a, dtype=np.int64) for a in (starts, firsts, stops))
    n = int(np.sum(stops - firsts))
    x, dx = np.empty(n), np.empty((n, 4))
    _sensitivity_spans(
        _as_input(u),
        params.m_left,
        params.c_left,
        params.m_right,
        params.c_right,
        starts,
        firsts,
        stops,
        np.ascontiguousarray(x0s, dtype=float),
        x,
        dx,
    )
    return x, dx


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


@dataclass(frozen=True)
class PaperExample:
    """One of the five examples of the paper's section 5 (see ``PAPER.md``).

    Attributes
    ----------
    number : int
        1-5, as in the paper.
    params : BacklashParams
        True backlash parameters.
    a, b : tuple of float
        The linear block of eq. (15)-(17), ``a = (a2, ...)`` with ``a1 = 1`` and ``b = (b1, ...)``;
        empty for backlash alone (examples 1, 2).
    samples : int
        Number of samples.
    snr : float
        Signal-to-noise ratio ``sqrt(var(output) / var(noise))``.
    paper_iterations : int
        Iterations the paper reports for its algorithm to converge.
    """

    number: int
    params: BacklashParams
    a: tuple[float, ...]
    b: tuple[float, ...]
    samples: int
    snr: float
    paper_iterations: int

    @property
    def cascade(self) -> bool:
        """True for examples 3-5 (backlash followed by a linear system)."""
        return bool(self.a or self.b)

    def parameters(self) -> dict[str, float]:
        """True values by name: ``m_left, c_left, m_right, c_right`` and ``a2.., b1..`` of a cascade."""
        p = self.params
        out = {"m_left": p.m_left, "c_left": p.c_left, "m_right": p.m_right, "c_right": p.c_right}
        out.update({f"a{i}": v for i, v in enumerate(self.a, start=2)})
        out.update({f"b{j}": v for j, v in enumerate(self.b, start=1)})
        return out

    def generate(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Input and noisy output ``(u, y)`` of the example for one random ``seed``.

        The input is uniform on ``(-1, 1)``; the output (``x`` for backlash alone, ``y`` of
        eq. 15 for a cascade) gets zero-mean Gaussian noise of standard deviation
        ``std(output) / snr``. The backlash starts at rest at ``x(-1) = 0``.
        """
        rng = np.random.default_rng(seed)
        u = rng.uniform(-1.0, 1.0, self.samples)
        out = simulate_backlash(u, self.params)
        if self.cascade:
            out = linear_filter(out, np.asarray(self.a), np.asarray(self.b))
        return u, out + rng.normal(0.0, np.std(out) / self.snr, self.samples)


_PAPER_LINEAR = ((0.5,), (-0.2, 0.35))  # y(t) = x(t-1) + 0.5 x(t-2) + 0.2 y(t-1) - 0.35 y(t-2)

#: The paper's five examples, by number.
PAPER_EXAMPLES: dict[int, PaperExample] = {
    1: PaperExample(1, BacklashParams(1.3, 0.5, 2.5, 0.7), (), (), 800, 10.0, 7),
    2: PaperExample(2, BacklashParams(1.7, 0.1, 1.4, 0.15), (), (), 800, 10.0, 5),
    3: PaperExample(3, BacklashParams(1.3, 0.6, 2.0, 0.7), *_PAPER_LINEAR, 1500, 25.0, 9),
    4: PaperExample(4, BacklashParams(0.24, 0.035, 0.26, 0.07), *_PAPER_LINEAR, 1500, 25.0, 4),
    5: PaperExample(5, BacklashParams(-1.3, 0.2, -1.3, 0.2), *_PAPER_LINEAR, 1500, 25.0, 5),
}

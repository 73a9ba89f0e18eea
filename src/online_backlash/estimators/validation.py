"""Input and parameter checks shared by the estimators (scikit-learn style: validate at fit)."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from ..errors import InvalidParameterError, NotExcitedError, NotFittedError

#: Largest input or output magnitude a fit accepts: float64 spaces numbers beyond it more than 0.1 apart,
#: and the squares in the normal equations overflow long before 1e300.
MAX_MAGNITUDE = 1e15


def finite(name: str, value: float) -> float:
    """``value`` as a float; InvalidParameterError if it is not finite (NaN never reaches an estimator)."""
    v = float(value)
    if not math.isfinite(v):
        raise InvalidParameterError(f"{name} must be finite, got {value!r}")
    return v


def finite_array(name: str, value: Any) -> np.ndarray:
    """``value`` as a contiguous float array; InvalidParameterError naming the first non-finite index."""
    arr = np.ascontiguousarray(value, dtype=float)
    # a finite sum (one pass, no temporary) proves every value finite; else look closer
    if not math.isfinite(float(np.sum(arr))) and not np.all(np.isfinite(arr)):
        raise InvalidParameterError(
            f"{name} has non-finite values, first at index {int(np.flatnonzero(~np.isfinite(arr))[0])}"
        )
    return arr


def check_magnitude(**arrays: np.ndarray) -> None:
    """Raise InvalidParameterError if a named array holds a value beyond :data:`MAX_MAGNITUDE` (e.g. 1e300:
    wrong units)."""
    for name, arr in arrays.items():
        big = np.flatnonzero(np.abs(arr) > MAX_MAGNITUDE)
        if big.size:
            raise InvalidParameterError(
                f"{name} reaches {arr[big[0]]:.3g} at index {big[0]}: values beyond {MAX_MAGNITUDE:g} cannot be "
                "fitted in float64; check the units"
            )


def check_pair(u: np.ndarray, y: np.ndarray, *, min_samples: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Return ``u`` and ``y`` as finite 1-D float arrays of equal length, or raise InvalidParameterError."""
    u = np.ascontiguousarray(u, dtype=float)
    y = np.ascontiguousarray(y, dtype=float)
    if u.ndim != 1 or y.ndim != 1:
        raise InvalidParameterError(f"u and y must be 1-D, got shapes {u.shape} and {y.shape}")
    if u.shape != y.shape:
        raise InvalidParameterError(f"u and y must have equal length, got {u.size} and {y.size}")
    if u.size < min_samples:
        raise InvalidParameterError(f"need at least {min_samples} samples, got {u.size}")
    for name, arr in (("u", u), ("y", y)):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise InvalidParameterError(f"{name} has {bad.size} non-finite values, first at index {bad[0]}")
    check_magnitude(u=u, y=y)
    return u, y


def check_reverses(u: np.ndarray) -> None:
    """Raise NotExcitedError unless ``u`` moves in both directions (both flanks of the dead band are seen)."""
    du = np.diff(u)
    if not (np.any(du > 0) and np.any(du < 0)):
        raise NotExcitedError(
            "the input never reverses: both flanks of the dead band must be engaged to identify "
            "backlash (eq. 5-6); record a motion that changes direction"
        )


def check_int(name: str, value: object, low: int, high: int | None = None) -> int:
    """Validate an integer parameter in ``[low, high]``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidParameterError(f"{name} must be an int, got {type(value).__name__} {value!r}")
    v = int(value)
    if v < low or (high is not None and v > high):
        rng = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise InvalidParameterError(f"{name} must be {rng}, got {value}")
    return v


def check_real(name: str, value: object, low: float, *, low_open: bool = True) -> float:
    """Validate a real parameter greater than (or equal to) ``low``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise InvalidParameterError(f"{name} must be a finite real number, got {value!r}")
    if value < low or (low_open and value == low):
        op = ">" if low_open else ">="
        raise InvalidParameterError(f"{name} must be {op} {low}, got {value}")
    return float(value)


def check_option(name: str, value: object, options: tuple[str, ...]) -> str:
    """Validate a string option."""
    if value not in options:
        raise InvalidParameterError(f"{name} must be one of {options}, got {value!r}")
    return str(value)


def check_is_fitted(estimator: object, attribute: str = "n_iter_") -> None:
    """Raise NotFittedError if ``estimator`` has no fitted ``attribute``."""
    if not hasattr(estimator, attribute):
        raise NotFittedError(f"this {type(estimator).__name__} is not fitted yet; call fit (or learn_one) first")

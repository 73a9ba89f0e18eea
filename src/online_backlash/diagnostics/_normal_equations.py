"""Least squares from cross-products (normal equations), for full-length columns fitted many times.

A record of a few minutes at 1 kHz has 10^5-10^6 samples and a few dozen candidate columns. Every
least-squares quantity the loop needs (coefficients, the sum of squares left, the Gram matrix
of what some columns leave of others) follows from the Gram matrix ``W^T W`` of the columns
involved, which is formed once (``O(n k^2)``); each fit after that is a small solve. The
solves scale the Gram matrix to unit diagonal and use a truncated eigen-decomposition, so
degenerate directions get no weight instead of a huge one.

Units: whatever the columns carry (degrees in this package).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numba import njit

#: relative size below which a direction of the (scaled) normal equations counts as degenerate
RCOND = 1e-10


def pinv_factor(gram: np.ndarray) -> np.ndarray:
    """``F`` with ``F F^T`` the pseudo-inverse of the Gram matrix ``gram`` (scaled to unit diagonal,
    directions below :data:`RCOND` of the largest dropped)."""
    d = np.sqrt(np.maximum(np.diag(gram), 1e-300))
    w, v = np.linalg.eigh(gram / d[:, None] / d[None, :])
    keep = w > RCOND * max(float(w[-1]), 1e-300) if w.size else np.zeros(0, bool)
    return (v[:, keep] / np.sqrt(w[keep])) / d[:, None]


class EigenSolve:
    """The normal equations ``gram c = rhs`` of one Gram matrix, scaled to unit diagonal and decomposed once
    (truncated eigen-decomposition: degenerate directions get no weight); ``self(rhs)`` solves them for one
    right-hand side, as :func:`solve` does, number for number."""

    def __init__(self, gram: np.ndarray) -> None:
        self.scale = np.sqrt(np.maximum(np.diag(gram), 1e-300))
        d = self.scale
        w, v = np.linalg.eigh(gram / d[:, None] / d[None, :])
        keep = w > RCOND * max(float(w[-1]), 1e-300)
        self.vectors, self.values = v[:, keep], w[keep]

    def __call__(self, rhs: np.ndarray) -> np.ndarray:
        c = self.vectors @ ((self.vectors.T @ (rhs / self.scale)) / self.values)
        return c / self.scale


def solve(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Least-squares coefficients ``c`` from the normal equations ``gram c = rhs``, scaled to unit
    diagonal and solved by a truncated eigen-decomposition (degenerate directions get no weight)."""
    return EigenSolve(gram)(rhs)


def fit_rss(gram: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, float]:
    """Coefficients on the columns ``cols`` of ``W`` and the sum of squares they leave of ``W``'s
    last column, from ``gram = W^T W``."""
    c = solve(gram[np.ix_(cols, cols)], gram[cols, -1])
    return c, float(gram[-1, -1] - c @ gram[cols, -1])


def left_sum_of_squares(gram: np.ndarray) -> float:
    """What the least squares of ``W``'s last column on the others leaves, ``|r|^2``, from ``W^T W``."""
    return max(fit_rss(gram, np.arange(gram.shape[0] - 1))[1], 0.0)


class Columns(Protocol):
    """Columns ``C`` (n x q) as least squares use them: ``gram()`` is ``C^T C``, ``t_dot(a)`` is
    ``C^T a``, ``dot(coef)`` is ``C coef`` (columns kept in parts need not be put side by side)."""

    @property
    def shape(self) -> tuple[int, int]: ...

    def gram(self) -> np.ndarray: ...

    def t_dot(self, a: np.ndarray) -> np.ndarray: ...

    def dot(self, coef: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class Dense:
    """:class:`Columns` of one array."""

    array: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        n, q = self.array.shape
        return n, q

    def gram(self) -> np.ndarray:
        return self.array.T @ self.array

    def t_dot(self, a: np.ndarray) -> np.ndarray:
        return self.array.T @ a

    def dot(self, coef: np.ndarray) -> np.ndarray:
        return self.array @ coef


class Projector:
    """Least squares on fixed columns ``C`` (n x q), from their Gram matrix formed once.

    ``coef(v)``: the coefficients of ``v`` on ``C``; ``leave(v)``: the part of ``v`` they leave;
    ``left_gram(a)``: the Gram matrix of what they leave of every column of ``a`` (n x k),
    ``O(n q k)`` without forming it. ``columns``: an array, or :class:`Columns` (in parts).
    """

    def __init__(self, columns: np.ndarray | Columns) -> None:
        self.columns: Columns = Dense(columns) if isinstance(columns, np.ndarray) else columns
        self.factor = pinv_factor(self.columns.gram()) if self.columns.shape[1] else np.empty((0, 0))

    def coef(self, v: np.ndarray) -> np.ndarray:
        return self.coef_of(self.columns.t_dot(v)) if self.columns.shape[1] else np.empty(0)

    def coef_of(self, cross: np.ndarray) -> np.ndarray:
        """The coefficients of ``v`` on ``C`` from ``cross = C^T v``."""
        return self.factor @ (self.factor.T @ cross)

    def leave(self, v: np.ndarray) -> np.ndarray:
        return v - self.columns.dot(self.coef(v)) if self.columns.shape[1] else v

    def left_gram(self, a: np.ndarray, cross: np.ndarray | None = None) -> np.ndarray:
        """``(P a)^T (P a)`` with ``P`` the projection off ``C``; ``cross`` is ``C^T a`` if known."""
        if not self.columns.shape[1]:
            return a.T @ a
        return self.left_of(a.T @ a, self.columns.t_dot(a) if cross is None else cross)

    def left_of(self, gram: np.ndarray, cross: np.ndarray) -> np.ndarray:
        """``(P a)^T (P a)`` from ``gram = a^T a`` and ``cross = C^T a`` (``a`` itself not needed)."""
        if not self.columns.shape[1]:
            return gram
        b = self.factor.T @ cross
        return gram - b.T @ b


def nonzero_rows(columns: np.ndarray, most: int | None = None) -> np.ndarray | None:
    """The rows of ``columns`` (``(n, k)``) with a value other than zero, increasing (one compiled pass);
    None as soon as there are more than ``most`` of them (the pass stops there: dense columns cost
    little)."""
    c = np.asarray(columns, dtype=float)
    rows = np.empty(c.shape[0], dtype=np.int64)
    found = _nonzero_rows(c, rows, c.shape[0] if most is None else int(most))
    return None if found < 0 else rows[:found].copy()


@njit(cache=True)
def _nonzero_rows(c, rows, most):  # pragma: no cover - compiled
    """Writes the rows of ``c`` with a nonzero value into ``rows``; their count, or -1 past ``most``."""
    found = 0
    for t in range(c.shape[0]):
        for j in range(c.shape[1]):
            if c[t, j] != 0.0:
                if found == most:
                    return -1
                rows[found] = t
                found += 1
                break
    return found

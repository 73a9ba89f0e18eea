"""Flat state vectors of the compiled kernels, declared once as named fields.

A layout is a ``NamedTuple`` class whose fields are the vector's fields, in order, and whose
defaults are their sizes. :func:`offsets` turns it into the same ``NamedTuple`` holding each
field's offset, plus the total size, once at import. The kernels index with those offsets
(``st[S.N_SEEN]``; numba freezes a global tuple as constants, so this costs nothing compiled)
and the Python side builds and reads vectors by the same names (:func:`pack`): no offset is
counted by hand.

Examples
--------
>>> from typing import NamedTuple
>>> class Demo(NamedTuple):
...     COUNT: int = 1
...     LINE: int = 2
...     LEVEL: int = 1
>>> offsets(Demo())
(Demo(COUNT=0, LINE=1, LEVEL=3), 4)
>>> D, size = offsets(Demo())
>>> pack(D, size, COUNT=5.0, LEVEL=0.5)
[5.0, 0.0, 0.0, 0.5]
"""

from __future__ import annotations

from typing import Any, TypeVar

T = TypeVar("T", bound=tuple)


def offsets(sizes: T) -> tuple[T, int]:
    """``(layout of offsets, total size)`` from a ``NamedTuple`` instance of field sizes."""
    out = []
    at = 0
    for size in sizes:
        if int(size) < 1:
            raise ValueError(f"field sizes must be >= 1, got {sizes}")
        out.append(at)
        at += int(size)
    make: Any = type(sizes)  # the NamedTuple class
    return make(*out), at


def pack(layout: tuple, size: int, **values: float) -> list[float]:
    """A vector of ``size`` zeros with the named scalar fields of ``layout`` (offsets) set."""
    vec = [0.0] * size
    for name, value in values.items():
        vec[getattr(layout, name)] = float(value)
    return vec

"""Single-turn absolute encoder counts to a multi-turn count.

An absolute encoder of ``counts_per_rev`` counts (``2**bits`` for a ``bits``-bit encoder) wraps
from ``counts_per_rev - 1`` to 0 once per revolution. Between two readings the shaft is assumed
to have turned less than half a revolution (sampling fast enough); the step is then the signed
difference modulo ``counts_per_rev``. After a gap long enough for the shaft to turn half a
revolution or more the turn count is ambiguous and the unwrapped angle may be off by whole turns.
"""

from __future__ import annotations

from online_backlash.errors import InvalidParameterError


class Unwrapper:
    """Accumulate wrapping counts into a multi-turn count (integers, so no rounding drift).

    Parameters
    ----------
    modulus : int or None
        Counts per wrap: counts per revolution of a single-turn encoder, or ``2**32`` for the
        rollover of a 32-bit counter. None: the values are multi-turn already and pass unchanged.

    Examples
    --------
    >>> u = Unwrapper(16)
    >>> [u(c) for c in (14, 15, 0, 1, 0, 15)]
    [14, 15, 16, 17, 16, 15]
    >>> u = Unwrapper(None)
    >>> [u(c) for c in (14, 15, 0)]
    [14, 15, 0]
    """

    __slots__ = ("_half", "_last", "_total", "modulus")

    def __init__(self, modulus: int | None) -> None:
        if modulus is not None and (not isinstance(modulus, int) or modulus < 2):
            raise InvalidParameterError(f"modulus must be an integer >= 2, got {modulus!r}")
        self.modulus = modulus
        self._half = 0 if modulus is None else modulus // 2
        self._last: int | None = None
        self._total = 0

    def __call__(self, count: int) -> int:
        """The multi-turn count for the next reading ``count`` (``0 <= count < modulus`` or any int)."""
        if self._last is None or self.modulus is None:
            self._total = count
        else:
            step = (count - self._last) % self.modulus
            if step > self._half:
                step -= self.modulus
            self._total += step
        self._last = count
        return self._total

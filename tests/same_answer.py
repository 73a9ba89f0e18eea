"""``assert_same_answer``: two ``diagnose --json`` objects (or any nested JSON) that say the same thing.

Names, counts and every other non-float value must be equal; floats equal to ``rel`` of their size
(a joint refit started nearer its end stops at the same least squares to the search's tolerance, not
to the last bit). NaN equals NaN.
"""

from __future__ import annotations

import math
from typing import Any


def assert_same_answer(a: Any, b: Any, rel: float = 1e-8, path: str = "") -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), f"{path}: keys {sorted(a)} vs {sorted(b)}"
        for k in a:
            assert_same_answer(a[k], b[k], rel, f"{path}.{k}")
    elif isinstance(a, list | tuple) and isinstance(b, list | tuple):
        assert len(a) == len(b), f"{path}: {len(a)} vs {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_answer(x, y, rel, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float | int) and not isinstance(b, bool):
        same = a == b or (math.isnan(a) and math.isnan(b)) or abs(a - b) <= rel * max(abs(a), abs(b))
        assert same, f"{path}: {a!r} vs {b!r} (relative {rel})"
    else:
        assert a == b, f"{path}: {a!r} vs {b!r}"
